"""What the person at the bench is told."""

from __future__ import annotations

import re

import numpy as np

from imucal_cli.design.poses import describe_direction
from imucal_cli.plans import Step


def instruction(step: Step) -> str:
    """What the person is told for a step: ``"Put face +Z up and hold still"``,
    ``"Turn about +X by 90 degrees, then hold still"``."""
    label = step.label.strip()
    if step.kind == "rotation":
        if step.axis is not None:
            text = f"Turn about {describe_direction(np.asarray(step.axis, float))}"
            if step.angle_deg is not None:
                text += f" by {step.angle_deg:g} degrees"
            return text + ", then hold still"
        return label[:1].upper() + label[1:] + ", then hold still"
    low = label.lower()
    if low.startswith(("face ", "edge ")):
        return f"Put {label} and hold still"
    if re.fullmatch(r"pose \d+", low):
        return f"Put the unit in a new orientation ({label}) and hold still"
    if step.up is not None:
        return f"Put the unit {label} ({describe_direction(np.asarray(step.up))} up) and hold still"
    text = label[:1].upper() + label[1:]
    return text if "still" in low else text + " and hold still"


def fmt_vec(v: np.ndarray) -> str:
    """A vector in fixed-width columns (live signal, noise)."""
    return " ".join(f"{x:9.4g}" for x in np.asarray(v, float))
