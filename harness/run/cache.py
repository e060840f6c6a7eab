"""The content key of one run, and the checksums of its outputs.

The key covers everything that decides a result: the generated main.edp and FreeFEM's
options, the harness code that writes them, the solver sources, the material file the scene
uses and every file its materials include (recursively), the mesh, the scene values, the
start (a coarser level by *its* key, so that round-off differences between identical runs
do not invalidate the levels above) and the FreeFEM version. A cached level is reused only
when its key matches and every output still has the checksum it was written with."""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import sys
from pathlib import Path
from typing import Any

from harness.core.errors import FieldsError
from harness.core.layout import REPO
from harness.run.record import RunRecord, read_run_json

# The harness modules whose code turns a scene into FreeFEM's inputs (main.edp, options,
# macros): an edit to any of them may change a result without changing the scene.
INPUT_WRITERS = ("harness.run.script", "harness.core.freefem", "harness.run.run", "harness.scene.mms", "harness.scene.scene",
                 "harness.scene.schema", "harness.core.contract", "harness.scene.unknowns", "harness.run.cache", "harness.study.engine",
                 "harness.scene.floating", "harness.run.plan", "harness.scene.linear_solvers",
                 "harness.scene.quantities", "harness.run.quantities")
CHECKSUMS = "checksums.json"
# Written after the checksums, or by the harness about the cache itself.
UNCHECKED = frozenset({CHECKSUMS})


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@functools.lru_cache(maxsize=1024)
def _source_sha256(path: str, mtime_ns: int, size: int) -> str:
    return sha256_file(Path(path))


def source_sha256(path: Path) -> str:
    """sha256_file of a source file, hashed once per process while it is unchanged (same
    modification time and size): every level of a study keys the same ~50 files."""
    stat = path.stat()
    return _source_sha256(str(path), stat.st_mtime_ns, stat.st_size)


def source_digests(freefem_dir: Path, material: Path | None = None,
                   included: tuple[Path, ...] = ()) -> dict[str, str]:
    """Every .idp/.edp under freefem/ by relative path, except the materials: of those only
    `material`, the one the scene uses (adding or editing another invalidates nothing), and
    the files its materials include (`included`, harness/scene/materials.py included_files)."""
    materials = freefem_dir / "materials"
    files = sorted(p for p in freefem_dir.rglob("*")
                   if p.suffix in (".idp", ".edp") and p.is_file() and materials not in p.parents)
    digests = {str(p.relative_to(freefem_dir)): source_sha256(p) for p in files}
    if material is not None:  # a library material by its path in freefem/, a user's own by its name
        digests[source_name(material, freefem_dir, material.resolve().parent)] = source_sha256(material)
        for path in included:  # by its path beside the material's, so that two of one name stay two
            digests[source_name(path, freefem_dir, material.resolve().parent)] = source_sha256(path)
    return digests


def source_name(path: Path, freefem_dir: Path, beside: Path) -> str:
    """A keyed file's name: its path in freefem/, or outside it `<material>/` and its path from
    the folder `beside` (the scene's material file's), so the key does not hold where a clone lives."""
    path = path.resolve()
    if path.is_relative_to(freefem_dir.resolve()):
        return str(path.relative_to(freefem_dir.resolve()))
    return f"<material>/{os.path.relpath(path, beside)}"


def code_digests(modules: tuple[str, ...] = INPUT_WRITERS) -> dict[str, str]:
    """The source of each input-writing module that exists (found, not imported)."""
    out = {}
    for name in modules:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin and Path(spec.origin).is_file():
            out[name] = source_sha256(Path(spec.origin))
    return out


def portable(text: str, freefem_dir: Path) -> str:
    """main.edp names its includes by absolute path: key it by what it includes, not where
    the clone lives."""
    for root, name in ((freefem_dir.resolve(), "<freefem>"), (REPO, "<repo>")):
        text = text.replace(str(root), name)
    return text


def run_inputs(mesh: Path, scene: dict[str, Any], freefem_dir: Path, version: str, n: int,
               script: str = "", options: tuple[str, ...] = (), material: Path | None = None,
               included: tuple[Path, ...] = ()) -> dict[str, Any]:
    inputs = {
        "n": n,
        "mesh_sha256": sha256_file(mesh),
        "scene": scene,
        "main_edp_sha256": sha256_bytes(portable(script, freefem_dir).encode()),
        "options": list(options),
        "sources": source_digests(freefem_dir, material, included),
        "harness_code": code_digests(),
        "freefem_version": version,
    }
    inputs["key"] = sha256_bytes(canonical_json(inputs).encode())
    return inputs


def canonical_json(value: Any) -> str:
    # allow_nan: a scene may hold inf (L = inf), which JSON spells Infinity.
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)


def write_checksums(directory: Path) -> None:
    """checksums.json: the SHA-256 of every file the run left in `directory`."""
    sums = {p.name: sha256_file(p) for p in sorted(directory.iterdir()) if p.is_file() and p.name not in UNCHECKED}
    (directory / CHECKSUMS).write_text(json.dumps(sums, indent=2, sort_keys=True) + "\n")


def corrupted(directory: Path) -> str | None:
    """What is wrong with a cached run's outputs (a file missing or changed since it was
    written), or None when every checksum matches."""
    try:
        sums = json.loads((directory / CHECKSUMS).read_text())
    except (OSError, ValueError):
        return f"no readable {CHECKSUMS}"
    for name, digest in sums.items():
        path = directory / name
        if not path.is_file():
            return f"{name} is missing"
        if sha256_file(path) != digest:
            return f"{name} does not match its checksum"
    return None


def cached_record(directory: Path, key: str) -> RunRecord | None:
    """run.json of a reusable cached run: same key, converged, outputs intact. A corrupted
    one is reported in one warning line and rerun."""
    try:
        stored = json.loads((directory / "inputs.json").read_text())
        record = read_run_json(directory)
    except (OSError, ValueError, FieldsError):  # FieldsError: written by another version
        return None
    if stored.get("key") != key or record is None or record.converged is not True:
        return None
    problem = corrupted(directory)
    if problem:
        print(f"warning: {directory}: {problem}; rerunning this level", file=sys.stderr, flush=True)
        return None
    return record


def stored_key(directory: Path) -> str | None:
    try:
        return json.loads((directory / "inputs.json").read_text()).get("key")
    except (OSError, ValueError, AttributeError):
        return None
