"""Known-answer checks of what the SocketCAN tests rely on, run on the host and in the guest.

`.ci/socketcan/run` runs this with the project's Python on the host first and inside the
guest before the command; the two digests must match. It exercises, in two threads at once
and with fresh memory (page faults) all the time, the code paths that pick vector
instructions at run time: glibc's string and memory functions (through CPython's bytes and
str operations), OpenSSL (hashlib), zlib, the re engine, json, pydantic-core (Rust: memchr
and its own SIMD dispatch) and ruamel.yaml. A guest whose vector state is corrupted gives
another digest (or crashes), and the runner refuses that guest. Prints one line: the digest.
"""

from __future__ import annotations

import hashlib
import io
import json
import re
import sys
import threading
import zlib

ROUNDS = 24


def workload(seed: int) -> str:
    digest = hashlib.sha256()
    for round_ in range(ROUNDS):
        size = 65536 + 4099 * ((seed * 31 + round_) % 97)
        block = hashlib.shake_256(bytes([seed, round_])).digest(size)  # fresh pages
        text = block.hex()
        digest.update(hashlib.sha512(block).digest())
        digest.update(hashlib.blake2b(block).digest())
        digest.update(zlib.compress(block, 6))
        digest.update(str(block.find(bytes([seed, round_ & 0xFF]))).encode())
        digest.update(str(text.count("a7")).encode())
        digest.update(str(text.upper().rfind("F0E")).encode())
        digest.update(block[1000:5000] + block[7:3007])  # memcpy
        digest.update(str(block == bytes(block)).encode())  # memcmp
        digest.update(str(len(re.findall(rb"\x07[\x00-\x40]+", block))).encode())
        parsed = json.loads(
            json.dumps({"n": round_, "text": text[:4096], "list": list(block[:512])})
        )
        digest.update(json.dumps(parsed, sort_keys=True).encode())
        digest.update(text.replace("0", "zero").encode("utf-8"))
    return digest.hexdigest()


def libraries() -> str:
    """pydantic-core and ruamel.yaml, when installed (the tests' topology path)."""
    digest = hashlib.sha256()
    try:
        import pydantic
        from ruamel.yaml import YAML
    except ImportError:
        return "absent"

    class Point(pydantic.BaseModel):
        name: str
        values: list[int]

    yaml = YAML(typ="safe")
    for round_ in range(ROUNDS):
        document = {
            "points": [
                {"name": f"p{i}-{'x' * (i % 50)}", "values": list(range(i % 40))}
                for i in range(100 + round_)
            ]
        }
        points = [Point.model_validate(p) for p in document["points"]]
        digest.update(pydantic.TypeAdapter(list[Point]).dump_json(points))
        digest.update(
            str(
                pydantic.TypeAdapter(str).validate_json('"' + "ab" * 3000 + '"').find("ba")
            ).encode()
        )
        if round_ % 8 == 0:  # ruamel.yaml is slow: a small document now and then
            stream = io.StringIO()
            yaml.dump({"points": document["points"][:20]}, stream)
            digest.update(json.dumps(yaml.load(stream.getvalue()), sort_keys=True).encode())
    return digest.hexdigest()


def main() -> int:
    results: dict[str, str] = {}

    def run(name: str, job) -> None:  # type: ignore[no-untyped-def]
        results[name] = job()

    threads = [
        threading.Thread(target=run, args=("a", lambda: workload(1))),
        threading.Thread(target=run, args=("b", lambda: workload(2))),
        threading.Thread(target=run, args=("lib", libraries)),
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    total = hashlib.sha256(json.dumps(results, sort_keys=True).encode()).hexdigest()
    sys.stdout.write(f"known-answers {total}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
