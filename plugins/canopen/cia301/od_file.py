"""The object dictionary of a device read from an EDS or DCF (:mod:`..device`): objects added
as canopen's import made them, entries described by the file, sub-indices the file does not
list, objects kept for the services but not served."""

from __future__ import annotations

from canopen import objectdictionary as cod

from .od import Dictionary


class FileDictionary(Dictionary):
    """A :class:`~.od.Dictionary` that takes its objects from a file as well as from services."""

    def add_object(self, obj: cod.ODVariable | cod.ODRecord | cod.ODArray) -> None:
        """An object as canopen's EDS/DCF import built it: its entries start at their defaults."""
        self.model.add_object(obj)
        members = [obj] if isinstance(obj, cod.ODVariable) else list(obj.subindices.values())
        for var in members:
            self._values[(var.index, var.subindex)] = self.default(var)
        self.generation += 1

    def adopt(self, var: cod.ODVariable) -> None:
        """Describe an entry by ``var`` (an EDS/DCF device's name, access, limits, default), an
        entry of an existing object or a new sub-index of one; its value restarts at that
        default unless a getter serves it."""
        index, sub = var.index, var.subindex
        obj = self.model.indices[index]
        if isinstance(obj, cod.ODVariable):
            self.model.indices[index] = var
            self.model.names[var.name] = var
        else:
            var.parent = obj
            obj.subindices[sub] = var
            obj.names[var.name] = var
        if (index, sub) not in self._getters:
            self._values[(index, sub)] = self.default(var)
        self.generation += 1

    def drop_entry(self, index: int, subindex: int) -> None:
        """Stop serving one sub-index of a record (0609 0011) whose owner keeps its value
        elsewhere (the PDO engine's parameters): an EDS device's file does not list it."""
        obj = self.model.indices[index]
        if not isinstance(obj, cod.ODVariable) and subindex in obj.subindices:
            var = obj.subindices.pop(subindex)
            obj.names.pop(var.name, None)
            self.generation += 1

    def hide(self, index: int) -> None:
        """Keep ``index`` for the services that read it, but do not serve it (SDO: 0602 0000;
        PDO mapping: no such entry; left out of the EDS)."""
        self._hidden.add(index)
        self.generation += 1
