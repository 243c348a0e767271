"""Fuzz target of topology files: the examples mutated into the loader."""

from __future__ import annotations

from pathlib import Path

from fuzz_base import Bytes, InvariantBroken, Target

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


TOKENS = (
    b"-1", b"1e309", b"null", b"[", b"{", b"}", b"]", b"!!python/object:os.system", b"&a", b"*a",
    b"~", b"0x7FF", b"true", b"\t", b"- ", b": ", b"'", b'"', b"\xff", b"\x00", b"<<: *a",
    b"99999999999999999999", b".nan", b"modules:", b"type: canopen", b"--- ", b"%YAML 1.1\n",
)  # fmt: skip


class YamlTarget(Target):
    """Topology files: the examples mutated (bytes, lines, YAML tokens) into the loader."""

    name = "yaml"
    max_len = 48

    def setup(self) -> None:
        from fieldgate.topology import TopologyError, load_topology

        self.error = TopologyError
        self.load = load_topology
        self.examples = [p.read_bytes() for p in sorted(EXAMPLES.glob("*.yaml"))]
        self.file = self.work_dir / "fuzz.yaml"
        self.valid = self.work_dir / "valid.yaml"
        self.valid.write_bytes(self.examples[0])

    def run(self, data: bytes) -> None:
        b = Bytes(data)
        text = bytearray(b.pick(self.examples))
        while b.more():
            at = (b.u16() * 7) % (len(text) + 1)
            kind = b.u8() % 5
            if kind == 0:
                text[at : at + b.u8() % 8] = b""
            elif kind == 1:
                text[at:at] = b.pick(TOKENS)
            elif kind == 2:
                text[at:at] = b.take(b.u8() % 4)
            elif kind == 3:
                lines = text.split(b"\n")
                i = b.u8() % len(lines)
                lines.insert(b.u8() % len(lines), lines[i])
                text = bytearray(b"\n".join(lines))
            else:
                end = text.find(b"\n", at)
                text[at : end if end >= 0 else len(text)] = b.pick(TOKENS)
        self.file.write_bytes(bytes(text))
        try:
            self.load(self.file, self.registry)
        except self.error:
            pass

    def check(self) -> None:
        try:
            self.load(self.valid, self.registry)
        except self.error as exc:
            raise InvariantBroken(f"the valid example no longer loads: {exc}") from exc
