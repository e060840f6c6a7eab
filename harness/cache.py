"""The content key of one run: what went in decides whether an old result can be reused."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any


def sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def source_digests(freefem_dir: Path) -> dict[str, str]:
    """Every .idp/.edp under freefem/, by relative path: any edit to the solver invalidates."""
    files = sorted(p for p in freefem_dir.rglob("*") if p.suffix in (".idp", ".edp") and p.is_file())
    return {str(p.relative_to(freefem_dir)): sha256_bytes(p.read_bytes()) for p in files}


def run_inputs(mesh: Path, scene: dict[str, Any], freefem_dir: Path, version: str, n: int) -> dict[str, Any]:
    inputs = {
        "n": n,
        "mesh_sha256": sha256_bytes(mesh.read_bytes()),
        "scene": scene,
        "sources": source_digests(freefem_dir),
        "freefem_version": version,
    }
    inputs["key"] = sha256_bytes(canonical_json(inputs).encode())
    return inputs


def canonical_json(value: Any) -> str:
    # allow_nan: a scene may hold inf (L = inf), which JSON spells Infinity.
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=True)
