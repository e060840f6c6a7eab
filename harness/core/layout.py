"""Where things live: the repository's solver scripts and the results tree of a case."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from harness.core.errors import SceneError

REPO = Path(__file__).resolve().parents[2]
# The solver's FreeFEM sources, the C++ plugin and the material library: the one place their folder is named.
FREEFEM = REPO / "freefem"


def is_material_path(material: str) -> bool:
    """`scene.material` names a file (it has a folder or the .idp suffix), not a library name."""
    return "/" in material or material.endswith(".idp")


def case_path(case_dir: Path, given: str, key: str) -> Path:
    """A path a case file gives (`key`: a material file, a .geo), relative to the case file's
    folder or absolute, as an absolute path with its links followed. A loop of symbolic links
    is a SceneError naming the key: Python 3.11's pathlib raises RuntimeError for it (3.13
    follows the loop no further, and the file's read then fails with ELOOP)."""
    try:
        return (case_dir / given).resolve()
    except RuntimeError:
        raise SceneError(f"{key} = {given!r}: a loop of symbolic links, not a file") from None


def results_root() -> Path:
    """`./results` under the working directory: a study writes where its user stands, not
    into the checkout the harness was installed from (the Makefile runs from the checkout's
    root, so its targets still write into the checkout's results/)."""
    return Path.cwd() / "results"


@dataclass(frozen=True)
class Layout:
    """results/<case>/{meshes/mesh_n<N>.msh, n<N>/, n<N>.failed/, convergence.*, summary.json}.

    `placed`: scenes whose directory is not results/<name> but the one given (a study's own
    sub-folders: adapt's reference and uniform levels, under its case's folder); `stepped`:
    scenes whose runs are an adaptive loop's steps, in step<N>/ (step<N>.failed/), a name no
    level of any study takes."""

    results: Path = field(default_factory=results_root)
    freefem: Path = FREEFEM
    placed: tuple[tuple[str, Path], ...] = ()
    stepped: tuple[str, ...] = ()

    def case_dir(self, case: str) -> Path:
        return dict(self.placed).get(case, self.results / case)

    def meshes_dir(self, case: str) -> Path:
        return self.case_dir(case) / "meshes"

    def level_name(self, case: str, n: int) -> str:
        return f"step{n}" if case in self.stepped else f"n{n}"

    def level_dir(self, case: str, n: int) -> Path:
        return self.case_dir(case) / self.level_name(case, n)

    def failed_dir(self, case: str, n: int) -> Path:
        return self.case_dir(case) / f"{self.level_name(case, n)}.failed"

    def material_library(self) -> Path:
        return self.freefem / "materials"

    def material_file(self, material: str) -> Path:
        """A library name's file in freefem/materials/, or the path a scene gave."""
        return Path(material) if is_material_path(material) else self.material_library() / f"{material}.idp"

    def material_reduction_file(self) -> Path:
        """Derives the plane-strain constants the scheme uses from a material's 3D set."""
        return self.freefem / "material.idp"

    def scheme_file(self) -> Path:
        return self.freefem / "scheme.idp"
