"""The FreeFEM code that depends on which fields a scene has, generated in one place.

Every piece of freefem/ that does something per field (declare it, assemble its loads,
mask it in the Newton vector, record its history, write it out) calls one of the loop
macros written here with a per-field macro of its own: `allFields(DO)` expands to
`DO(U, u, u1, Uh, U, Su, u) DO(P, p, ph, Ph, Phi, Sphi, phi) ...` for the fields present,
so an absent field's code is never compiled (the role IFMACRO blocks had in each piece).
The arguments of DO are, in order: the key of the field's arrays (dirU, histIncP), the
key of its varfs and loads (vLu, bp), its scaled unknown, its space, its scale
(scaling.idp), its equation's scale, and its name in run.json and the VTU as a string
(FreeFEM's Stringification pads with spaces).

Which fields there are follows from the effects: u always, phi with piezoelectricity,
theta with the thermal effect. theta feeds back into u and phi (thermal expansion M,
pyroelectric P) but depends on them only through the thermal contact conductance
p_c(u_nu - g) (paper 2.15). Without thermal contact it is one-way coupled: it is solved
first, alone and linearly, and enters the Newton system for (u, phi) as a load
("staggered"). With it, all fields are solved together. On several ranks theta is always
solved with the others (`monolithic`): the distributed scheme has one Newton system, and the
monolithic Newton solves the same discrete equations, so its answer is the staggered one's to
the solver's round-off (tests/test_petsc_ranks.py).

The dimension enters here too: the displacement's components (u1, u2 in 2D).
"""

from __future__ import annotations

from dataclasses import dataclass

from harness.scene.schema import EFFECTS


@dataclass(frozen=True)
class Field:
    name: str            # in run.json and solution.vtu
    key: str             # suffix of per-field arrays: dirU, maskP, histIncT
    low: str             # suffix of varfs and loads: vLu, vKpp, bt
    unknown: str         # the scaled unknown (u: its first component, whose [] is the whole vector)
    space: str
    scale: str           # physical value = scale * unknown (freefem/scaling.idp)
    equation_scale: str  # the field's equation is divided by it
    effect: str | None   # the effect that brings the field in (None: always there)
    contact: str | None  # the effect whose contact term enters the field's equation


FIELDS = (
    Field("u", "U", "u", "u1", "Uh", "U", "Su", None, "contact"),
    Field("phi", "P", "p", "ph", "Ph", "Phi", "Sphi", "piezoelectric", "electric_contact"),
    Field("theta", "T", "t", "th", "Qh", "Theta", "Stheta", "thermal", "thermal_contact"),
)

# Bulk coupling blocks K_{row col} and the effect each needs (forms.idp defines vK<row><col>).
BULK_BLOCKS = (("u", "u", None), ("u", "p", "piezoelectric"), ("p", "u", "piezoelectric"),
               ("p", "p", "piezoelectric"), ("u", "t", "thermal"), ("t", "t", "thermal"),
               ("p", "t", "pyroelectric"))


@dataclass(frozen=True)
class Unknowns:
    effects: tuple[str, ...]
    dimension: int = 2
    monolithic: bool = False   # theta in the Newton system even without thermal contact (ranks)

    @property
    def fields(self) -> tuple[Field, ...]:
        return tuple(f for f in FIELDS if f.effect is None or f.effect in self.effects)

    def ordered_effects(self) -> list[str]:
        return [e for e in EFFECTS if e in self.effects]

    @property
    def staggered(self) -> bool:
        """theta solved first, alone (see the module's docstring)."""
        return "thermal" in self.effects and "thermal_contact" not in self.effects and not self.monolithic

    @property
    def newton(self) -> tuple[Field, ...]:
        return tuple(f for f in self.fields if not (f.name == "theta" and self.staggered))

    def strategy(self) -> str:
        names = ", ".join(f.name for f in self.newton)
        text = f"monolithic Newton on ({names})"
        if self.staggered:
            text = f"staggered: theta (linear, one-way coupled), then Newton on ({names})"
        if "contact" not in self.effects:
            text += "; no contact: the problem is linear"
        return text

    def components(self) -> list[str]:
        return [f"u{i + 1}" for i in range(self.dimension)]

    def macros(self) -> list[str]:
        def loop(name: str, fields: tuple[Field, ...]) -> str:
            calls = " ".join(f"DO({f.key}, {f.low}, {f.unknown}, {f.space}, {f.scale}, {f.equation_scale}, \"{f.name}\")"
                             for f in fields)
            return f"macro {name}(DO) {calls} //"

        newton = {f.low for f in self.newton}
        present = {f.low for f in self.fields}

        def matrix(block: str, blocks: set[tuple[str, str]]) -> str:
            rows = [f.low for f in self.newton]
            cells = [", ".join(block.format(r=r, c=c) if (r, c) in blocks else "0" for c in rows) for r in rows]
            return cells[0] if len(rows) == 1 else "[" + ", ".join(f"[{row}]" for row in cells) + "]"

        # Bulk: every block of the fields present (the staggered theta's too).
        blocks = {(r, c) for r, c, effect in BULK_BLOCKS if effect is None or effect in self.effects}
        blocks = {(r, c) for r, c in blocks if r in present and c in present}
        space = {f.low: f.space for f in FIELDS}
        # The blocks only K needs are assembled in a scope that frees them once K is built
        # (freefem/bulk.idp); a staggered theta's blocks are kept for its solve and loads.
        kept = {(r, c) for r, c in blocks if self.staggered and "t" in (r, c)}

        def assemble(which: set[tuple[str, str]]) -> str:
            # Each block's time and peak memory go to the run's profile (freefem/profile.idp).
            return " ".join(f"matrix K{r}{c} = vK{r}{c}({space[c]}, {space[r]}); "
                            f'tProfile = profileAdd("bulk block K{r}{c}", tProfile);' for r, c in sorted(which))
        kept_blocks, bulk_blocks = assemble(kept), assemble(blocks - kept)

        def into_petsc(which: set[tuple[str, str]]) -> str:
            # With PETSc each block goes into the plugin's K and is freed before the next is
            # assembled (freefem/bulk.idp): K_uu, the largest, first, while nothing else is held.
            order = sorted(which, key=lambda rc: (rc != ("u", "u"), rc))
            return " ".join(f"{{ matrix K{r}{c} = vK{r}{c}({space[c]}, {space[r]}); "
                            f'tProfile = profileAdd("bulk block K{r}{c}", tProfile); '
                            f"if (petscBulkAdd(id, K{r}{c}, bulkOffset{r}, bulkOffset{c}) < 0) exit(exitInternal); "
                            f'tProfile = profileAdd("bulk K into PETSc", tProfile); }}' for r, c in order)
        petsc_blocks = into_petsc(blocks - kept)
        # Or the plugin's element kernel, each block's matrix read off its form (freefem/bulk_kernel.idp).
        kernel_blocks = " ".join(f"kernelBlock(id, {r}, {c})" for r, c in sorted(blocks - kept))
        # A staggered theta is a load on the Newton fields through their blocks K_rt.
        staggered = " ".join(f"real[int] k{r}t = K{r}t * th[]; b{r} -= k{r}t;"
                             for r, c in sorted(blocks) if c == "t" and r in newton)
        bulk_matrix = matrix("K{r}{c}", blocks)
        # Contact: the diagonal block of each Newton field (a zero block of its shape when its
        # contact term is off) and the block of its dependence on u, each on the quadrature that
        # freefem/forms.idp's contactForm selects (the nodes' during newton.idp's lumped start).
        tangent, residual = [], []
        on = {f.low: f.contact in self.effects for f in FIELDS}
        blocks = set()
        for f in self.newton:
            k = f.low
            tangent.append(f"matrix T{k}{k}; contactForm(T{k}{k}, vT{k}{k}, {f.space}, {f.space})" if on[k]
                           else f"matrix T{k}{k} = vZ{k}{k}({f.space}, {f.space});")
            blocks.add((k, k))
            if k != "u" and on[k]:
                tangent.append(f"matrix T{k}u; contactForm(T{k}u, vT{k}u, Uh, {f.space})")
                blocks.add((k, "u"))
        # Room in the plugin's K for the blocks of T that K lacks (a field's dependence on u
        # through the contact conductance): the first K + T then needs no wider copy of K.
        reserve = " ".join(f"{{ matrix R{r}{c} = vT{r}{c}({space[c]}, {space[r]}); "
                           f"if (petscBulkReserve(id, R{r}{c}, bulkOffset{r}, bulkOffset{c}) < 0) exit(exitInternal); }}"
                           for r, c in sorted(blocks) if r != c)
        for f in self.fields:
            body = f"contactForm(r, vR{f.low}, 0, {f.space})" if on[f.low] else "r = 0;"
            residual.append(f"macro contactR{f.low}(r) {body} //")
        vector = ", ".join(f.key for f in self.newton)
        quote = '\\"'
        return [
            "// ---- The fields of this scene (harness/scene/unknowns.py) ----",
            f"macro {'STAGGEREDTHETA' if self.staggered else 'NEWTONTHETA'} 1 //" if "thermal" in self.effects else "",
            f"macro DIMENSION {self.dimension} //",
            f"macro uElement [{', '.join(['ELEMENT'] * self.dimension)}] //",
            f"macro uUnknown [{', '.join(self.components())}] //",
            loop("allFields", self.fields),
            loop("scalarFields", self.fields[1:]),
            loop("newtonFields", self.newton),
            f"macro newtonVector(U, P, T) [{vector}] //",
            f"macro keptBlocks() {kept_blocks} //",
            f"macro bulkBlocks() {bulk_blocks} //",
            f"macro bulkMatrix() {bulk_matrix} //",
            f"macro bulkIntoPetsc(id) {petsc_blocks} //",
            f"macro bulkKernelBlocks(id) {kernel_blocks} //",
            f"macro staggeredThetaLoads() {staggered} //" if self.staggered else "",
            f"macro contactBlocks() {' '.join(tangent)} //",
            f"macro contactMatrix() {matrix('T{r}{c}', blocks)} //",
            f"macro contactReserve(id) {reserve or ';'} //",
            *residual,
            f'string newtonFieldNames = "{", ".join(f.name for f in self.newton)}";',
            f'string fieldsJson = "[{", ".join(quote + f.name + quote for f in self.fields)}]";',
            f'string effectsJson = "[{", ".join(quote + e + quote for e in self.ordered_effects())}]";',
            f'string strategy = "{self.strategy()}";',
            f"int unknownsPerNode = {self.dimension + len(self.fields) - 1};",
        ]
