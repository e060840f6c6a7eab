"""The per-field FreeFEM code comes from one table (harness/scene/unknowns.py)."""

from __future__ import annotations

import pytest

from harness.run.script import hand_script, hand_script_path
from harness.scene.unknowns import Unknowns

FULL = ("piezoelectric", "thermal", "pyroelectric", "contact", "friction", "electric_contact", "thermal_contact")


def test_committed_solve_edp_is_generated():
    # Regenerate with `python -m harness.run.script` after editing harness/scene/unknowns.py or script.py.
    assert hand_script_path().read_text() == hand_script()


@pytest.mark.parametrize("effects, newton, vector, blocks", [
    (FULL, "u, phi, theta", "[U, P, T]", "[[Kuu, Kup, Kut], [Kpu, Kpp, Kpt], [0, 0, Ktt]]"),
    (("thermal", "contact"), "u", "[U]", "Kuu"),           # theta staggered: not in the Newton system
    (("piezoelectric", "contact", "electric_contact"), "u, phi", "[U, P]", "[[Kuu, Kup], [Kpu, Kpp]]"),
])
def test_the_newton_system_follows_the_effects(effects, newton, vector, blocks):
    text = "\n".join(Unknowns(effects).macros())
    assert f'string newtonFieldNames = "{newton}";' in text
    assert f"macro newtonVector(U, P, T) {vector} //" in text
    assert f"macro bulkMatrix() {blocks} //" in text


def test_a_contact_term_that_is_off_gives_a_zero_block_and_no_residual():
    text = "\n".join(Unknowns(("piezoelectric", "thermal", "contact", "thermal_contact")).macros())
    assert "matrix Tpp = vZpp(Ph, Ph);" in text and "vTpu" not in text
    assert "macro contactRp(r) r = 0; //" in text
    assert "macro contactMatrix() [[Tuu, 0, 0], [0, Tpp, 0], [Ttu, 0, Ttt]] //" in text
