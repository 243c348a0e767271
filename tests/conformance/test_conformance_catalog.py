"""The case catalog: every case module is listed once, and the registry imports no case."""

from __future__ import annotations

import importlib
import pkgutil

from fieldgate.conformance import CASES, cases, catalog


def test_every_module_that_registers_cases_is_in_the_catalog() -> None:
    # import every module under cases/ (also one the catalog forgot), then compare
    for info in pkgutil.iter_modules(cases.__path__, cases.__name__ + "."):
        importlib.import_module(info.name)
    registering = {c.fn.__module__ for c in CASES.values()}
    listed = {m.__name__ for m in catalog.CASE_MODULES}
    # a listed package (cases/devicenet/, one module per service) registers through its modules
    assert {m if m in listed else m.rsplit(".", 1)[0] for m in registering} == listed
    assert len(listed) == len(catalog.CASE_MODULES) >= 12


def test_each_case_is_selected_from_its_own_module() -> None:
    ids = [c.id for c in catalog.select(["all", "delta-as300"])] + [
        c.id for c in catalog.select(["all"], protocol="devicenet")
    ]
    assert sorted(ids) == sorted(CASES) and len(ids) == len(set(ids))
