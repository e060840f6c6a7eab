"""When Tresca friction grips instead of rubbing: one warning line for a run whose Tresca
friction exceeds its contact force, or acts where Gamma_3 is open.

Tresca's slip bound S does not depend on the normal pressure (docs/model.md, "Tresca
friction"): the foundation holds the body with up to S per unit area even where nothing
presses it, so a copied S can return a friction many times the contact force, and every
physical check still passes (they test the law, and the law allows it). A device engineer's
law is usually Coulomb's, whose bound mu p vanishes with the pressure.
"""

from __future__ import annotations

from harness.run.record import RunRecord
from harness.scene.scene import Scene

# Friction over the open part of Gamma_3 at or below this share of the whole friction is
# round-off at points that sit exactly at the gap, not a grip.
OPEN_SHARE = 1e-9


def grip_warning(scene: Scene, record: RunRecord) -> str | None:
    """The warning line of a Tresca run that grips (None: no friction, Coulomb, or friction
    within the contact force and none where the contact is open). Friction is |sigma_tau|
    integrated over Gamma_3 (run.json's friction_total), what Coulomb would bound by mu times
    the contact force."""
    if "friction" not in scene.effects or scene.sections.contact.friction_law != "tresca":
        return None
    friction = record.friction_total or 0.0
    contact = record.contact_force or 0.0
    open_part = record.friction_open or 0.0
    on_open = open_part > OPEN_SHARE * friction
    if friction <= 0 or not (friction > contact or on_open):
        return None
    unit = "N" if scene.dimension == 3 else "N/m"
    where = f", {open_part:.3g} {unit} of it where the contact is open" if on_open else ""
    return (f"{scene.name} n={record.n}: Tresca friction {friction:.3g} {unit} against a contact force of "
            f"{contact:.3g} {unit}{where}: contact.S = {scene.sections.contact.S:g} N/m^2 grips the body "
            f"whatever the pressure; for a pressed contact use contact.friction_law = \"coulomb\" with contact.mu")
