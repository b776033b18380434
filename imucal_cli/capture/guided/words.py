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


NAMED_WITHIN_DEG = 5.0
"""A pose this close to a face or an edge is named after it, degrees."""


def _signed(k: int, value: float) -> str:
    return f"{'+' if value >= 0 else '-'}{'XYZ'[k]}"


def pose_name(up: np.ndarray) -> str:
    """A pose in words by its up direction (the unit's frame): ``"face +Z up"``, ``"edge
    +X-Z up"``, or ``"tilted 35 deg from face +Z up towards +X"``."""
    u = np.asarray(up, float) / np.linalg.norm(up)
    order = np.argsort(-np.abs(u))
    k1, k2 = int(order[0]), int(order[1])
    face = np.eye(3)[k1] * np.sign(u[k1] or 1.0)
    off = float(np.degrees(np.arccos(np.clip(u @ face, -1.0, 1.0))))
    if off <= NAMED_WITHIN_DEG:
        return f"face {_signed(k1, u[k1])} up"
    edge = face + np.eye(3)[k2] * np.sign(u[k2] or 1.0)
    edge_off = float(np.degrees(np.arccos(np.clip(u @ edge / np.sqrt(2.0), -1.0, 1.0))))
    if edge_off <= NAMED_WITHIN_DEG:
        a, b = sorted((k1, k2))
        return f"edge {_signed(a, u[a])}{_signed(b, u[b])} up"
    towards = describe_direction(u - (u @ face) * face)
    return f"tilted {off:.0f} deg from face {_signed(k1, u[k1])} up towards {towards}"


def turn_instruction(axis: np.ndarray, angle_deg: float, up_after: np.ndarray) -> str:
    """What the person is told for a proposed turn: ``"Turn about +X by 90 degrees
    (counter-clockwise seen from the +X end), to face +Y up, and hold still"``."""
    name = describe_direction(np.asarray(axis, float))
    sense = "" if abs(abs(angle_deg) - 180.0) < 1e-6 else (
        f" ({'counter-clockwise' if angle_deg > 0 else 'clockwise'} seen from the {name} end)")
    return (f"Turn about {name} by {abs(angle_deg):g} degrees{sense}, to {pose_name(up_after)}, "
            "and hold still")
