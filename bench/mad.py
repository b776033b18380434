"""imucal beside MaD Lab's ``imucal`` package on their Ferraris sessions (issue 9.3).

``../shared/data/imucal_ferraris``: (A) ``example_ferraris_session.csv`` (102.4 Hz, m/s^2 and
deg/s, a section list) and (B) ``annotated_session.csv`` (204.8 Hz, raw counts, a ``part``
column). Each is imported with ``imucal import --sections`` (faces and three 360-degree turns)
and calibrated with the default config (the labelled-pose accelerometer and the known-angle
gyro, :mod:`imucal_cli.calibrate.gyro.known`); MaD's ``FerrarisCalibration`` (PyPI ``imucal``,
the ``[bench]`` extra) runs on the same sections. Without that package the stored snapshot of
MaD's result for (B) (``imucal_snapshot_example_cal.json``) stands in, and the table says so.

* **Parameters side by side**: gyro gains (raw units per deg/s) and their std, bias, the
  angles between the gyro's axes (minus 90 deg), the rate std we state.
* **Held out**: (A) has five face-to-face moves that neither fit uses (the turns between the
  labelled faces; (B) has none: its sections are cut and joined, so its table says so instead
  of comparing, and the verdict rests on (A)). Each calibration's gyro is
  integrated over each move (the same integrator for both) and its prediction of the gravity
  direction after the move, from the one before, is compared with what that calibration's
  accelerometer reads there: RMS and largest error, degrees. Before (imucal with labels added
  by hand, the full model): about 2x MaD's.

* **Labelled by hand** (issue 24.5): (A) imported without the section list, its faces and
  three full turns labelled with ``imucal label``; each of its 12 face-to-face transitions
  (the 9 moves and the 3 known turns) left out of our calibration in turn and predicted,
  beside MaD's calibration (which none of them enters but its turns); and the known turns'
  angles as our calibration integrates them (within 2 of their std). Before: 1.42 deg against
  MaD's 0.67, the known y turn +3.8 degrees off; then 0.694 (the turns between still periods
  left out); 0.672 with the repeats of a face sharing its part of the placement (the labelled
  solver's face and hold parts; MaD 0.672: 0.6721 against 0.6716).
  Where the two differ (with MaD's package, the table says it): each calibration's
  accelerometer beside the other's gyro, and how far the two accelerometers put gravity at the
  same still periods apart (at most 0.106 deg, of which a common rotation of the frame, which
  the labels choose, is 0.068: ours weighs all 13 holds, 7 of them repeats of a face whose
  gravity sits up to 0.26 deg from that face's first hold, MaD's takes its six first sections
  as exact; within the frame 0.049 deg apart). Turned into MaD's frame our accelerometer
  predicts the move from -Y to +Z (segment 0009, where MaD's does best against ours) to 0.588
  deg instead of 0.660 (MaD 0.515), and the 12 to 0.659 instead of 0.672: the frame, within
  our stated std of 0.12 deg, is most of the difference, and which frame is the better the 12
  transitions cannot tell (paired standard error 0.0172 deg^2 against a mean difference of
  +0.0006; ours closer on 7 of 12).

Run alone: ``python -m bench --only mad``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from imucal_cli.estimators.gyro.integration import integrate_rotations
from imucal_cli.formats.calibration import read_calibration
from imucal_cli.formats.session import read_session
from imucal_cli.model.gyro import KnownTurnCheck

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "imucal_ferraris"
IMUCAL = str(Path(sys.executable).with_name("imucal"))
SESSIONS = {
    "A": ("example_ferraris_session.csv", "example_ferraris_session_list.json", 102.4,
          ("m/s^2", "deg/s")),
    "B": ("annotated_session.csv", "part", 204.8, ("a.u.", "a.u.")),
}  # fmt: skip
MIN_MOVE_S = 0.3  # a face-to-face move takes longer than this
#: MaD Lab imucal 2.6.0's gravity-direction error after each of the 12 face-to-face
#: transitions of session A (deg, in :func:`leave_one_out`'s order), measured by it: the
#: verdict's reference where the package is not installed (never a pass by default).  RMS
#: 0.6716 deg.  The 8th, 10th and 12th are the known 360-degree turns, which MaD's fit uses.
MAD_LOO_DEG = (0.1858, 1.3814, 0.5747, 0.3126, 0.5149, 0.3038, 1.2144, 0.0185, 0.5390, 0.0240,
               0.9583, 0.0110)  # fmt: skip
MAD_EXPECTED_ANGLE = -360.0  # MaD's default ("clockwise"); our import is told the same


def _ours(name: str, folder: Path):
    """Import with the sections, calibrate with the default config: (session, calibration)."""
    csv, sections, rate, _ = SESSIONS[name]
    h5, cal = folder / f"{name}.h5", folder / f"{name}.cal.json"
    sec = sections if not sections.endswith(".json") else str(DATA / sections)
    for args in (["import", str(DATA / csv), "--sections", sec, "--rate", str(rate),
                  "--turn-angle", str(MAD_EXPECTED_ANGLE), "-o", str(h5), "--force"],
                 ["calibrate", str(h5), "-o", str(cal), "--no-store", "--force"]):  # fmt: skip
        proc = subprocess.run([IMUCAL, *args], capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f"imucal {args[0]}: {proc.stderr.strip()}")
    return read_session(h5), read_calibration(cal)


class MadCal:
    """MaD's calibration as functions of raw samples: accel (m/s^2) and gyro (rad/s)."""

    def __init__(self, d: dict, source: str):
        self.d = {k: np.asarray(v, float) for k, v in d.items() if k[:2] in ("K_", "R_", "b_")}
        self.source = source

    def accel(self, raw):
        d = self.d
        return (np.linalg.inv(d["R_a"]) @ np.linalg.inv(d["K_a"]) @ (raw - d["b_a"]).T).T

    def gyro(self, raw, acc_cal):
        d = self.d
        z = raw - d["b_g"] - acc_cal @ d["K_ga"].T
        return np.radians((np.linalg.inv(d["R_g"]) @ np.linalg.inv(d["K_g"]) @ z.T).T)

    def gyro_gains(self) -> np.ndarray:  # raw units per deg/s of each axis
        S = self.d["K_g"] @ self.d["R_g"]
        return np.linalg.norm(S, axis=1)


def _mad(name: str) -> MadCal | None:
    """MaD's FerrarisCalibration on the same sections (the package), else the snapshot (B)."""
    csv, sections, rate, units = SESSIONS[name]
    try:
        import pandas as pd
        from imucal import FerrarisCalibration, ferraris_regions_from_df
        from imucal.ferraris_calibration import ferraris_regions_from_section_list
    except ImportError:
        if name != "B":
            return None
        d = json.loads((DATA / "imucal_snapshot_example_cal.json").read_text())
        return MadCal(d, "MaD's stored snapshot (package not installed)")
    if sections.endswith(".json"):
        df = pd.read_csv(DATA / csv, header=0, index_col=0)
        regions = ferraris_regions_from_section_list(df, pd.read_json(DATA / sections).T)
    else:
        regions = ferraris_regions_from_df(pd.read_csv(DATA / csv, index_col=[0, 1]))
    info = FerrarisCalibration(expected_angle=MAD_EXPECTED_ANGLE).compute(
        regions, rate, from_acc_unit=units[0], from_gyr_unit=units[1]
    )
    import imucal

    return MadCal({k: getattr(info, k) for k in ("K_a", "R_a", "b_a", "K_g", "R_g", "K_ga",
                                                  "b_g")}, f"MaD imucal {imucal.__version__}")


def _moves(session) -> tuple[list, dict[str, int]]:
    """The consecutive still pairs with a held-out move between them, and how many pairs are
    not one, by reason: ``"turn"`` (a calibration turn in between, used by both fits) and
    ``"cut"`` (no move recorded between them: sections cut and joined, session B)."""
    statics = session.static_segments()
    moves, skipped = [], {"turn": 0, "cut": 0}
    for s0, s1 in zip(statics, statics[1:], strict=False):
        if any(r.start >= s0.stop and r.stop <= s1.start for r in session.rotation_segments()):
            skipped["turn"] += 1
        elif session.time[s1.start] - session.time[s0.stop - 1] < MIN_MOVE_S:
            skipped["cut"] += 1
        else:
            moves.append((s0, s1))
    return moves, skipped


def held_out(session, accel_fn, gyro_fn) -> np.ndarray:
    """Gravity-direction error (deg) after each face-to-face move, predicted by the gyro."""
    out = []
    for s0, s1 in _moves(session)[0]:
        u0 = accel_fn(session.accel[s0.start : s0.stop]).mean(axis=0)
        u1 = accel_fn(session.accel[s1.start : s1.stop]).mean(axis=0)
        sl = slice(s0.stop - 1, s1.start + 1)
        w = gyro_fn(session.gyro[sl], accel_fn(session.accel[sl]))
        R = integrate_rotations([session.time[sl]], [w])[0]
        p = R.T @ (u0 / np.linalg.norm(u0))
        out.append(np.degrees(np.arccos(np.clip(p @ u1 / np.linalg.norm(u1), -1, 1))))
    return np.array(out)


def _no_held_out(skipped: dict[str, int]) -> str:
    """Why a session has no held-out move (the table says it instead of a comparison)."""
    parts = []
    if skipped["cut"]:
        parts.append(f"{skipped['cut']} face pairs joined with no move recorded between them "
                     "(sections cut and joined)")  # fmt: skip
    if skipped["turn"]:
        parts.append(f"{skipped['turn']} separated by a calibration turn both fits use")
    return "not comparable: no held-out move (" + "; ".join(parts or ["no still pairs"]) + ")"


def _axes_deg(S: np.ndarray) -> list[float]:
    s = S / np.linalg.norm(S, axis=1, keepdims=True)
    return [float(np.degrees(np.arccos(np.clip(s[i] @ s[j], -1, 1))) - 90)
            for i, j in ((0, 1), (0, 2), (1, 2))]  # fmt: skip


def compare(name: str, folder: Path) -> dict:
    """Our and MaD's parameters and held-out errors on one session."""
    session, cal = _ours(name, folder)
    mad = _mad(name)
    ours_gyro = cal.gyro
    moves, skipped = _moves(session)
    out = {"session": name, "mad_source": None if mad is None else mad.source,
           "ours_solver": None if ours_gyro is None else ours_gyro.solver,
           "ours_note": cal.gyro_note,
           "no_held_out": None if moves else _no_held_out(skipped)}  # fmt: skip
    if ours_gyro is not None:
        unit = np.pi / 180  # gains per deg/s
        S = np.linalg.inv(ours_gyro.matrix)
        out["ours"] = {"gyro_gain": (np.linalg.norm(S, axis=1) * unit).tolist(),
                       "gyro_gain_std": (np.asarray(ours_gyro.sensitivity_std)
                                         * unit).tolist(),
                       "gyro_bias": ours_gyro.bias.tolist(), "gyro_axes_deg": _axes_deg(S),
                       "rate_std": None if ours_gyro.rate_std is None
                       else ours_gyro.rate_std.total}  # fmt: skip
        out["ours_held_out"] = held_out(
            session, cal.accel.apply, lambda z, a: ours_gyro.apply(z, accel=a)).tolist()
    if mad is not None:
        S = mad.d["K_g"] @ mad.d["R_g"]
        out["mad"] = {"gyro_gain": mad.gyro_gains().tolist(), "gyro_bias": mad.d["b_g"].tolist(),
                      "gyro_axes_deg": _axes_deg(S)}  # fmt: skip
        out["mad_held_out"] = held_out(session, mad.accel, mad.gyro).tolist()
    return out


def labelled_session(folder: Path) -> Path:
    """Session (A) as a user without MaD's section list makes it (issue 24.5): ``imucal
    import`` (still periods found in the stream), ``imucal label --faces``, and each of the
    three full turns (the rotation segments longer than 3 s) labelled ``--angle -360`` about
    +X, +Y, +Z in turn."""
    from imucal_cli.formats.session import read_session as read

    csv, _, rate, units = SESSIONS["A"]
    h5 = folder / "A-labelled.h5"
    steps = [["import", str(DATA / csv), "--rate", str(rate), "--accel-units", units[0],
              "--gyro-units", units[1], "-o", str(h5), "--force"], ["label", str(h5), "--faces"]]
    for args in steps:
        proc = subprocess.run([IMUCAL, *args], capture_output=True, text=True, timeout=600)
        if proc.returncode != 0:
            raise RuntimeError(f"imucal {args[0]}: {proc.stderr.strip()}")
    session = read(h5)
    full = [r for r in session.rotation_segments() if r.stop - r.start > 3 * rate]
    for seg, axis in zip(full, ("1,0,0", "0,1,0", "0,0,1"), strict=True):
        proc = subprocess.run([IMUCAL, "label", str(h5), "--segment", seg.name, "--angle",
                               str(MAD_EXPECTED_ANGLE), "--axis", axis],
                              capture_output=True, text=True, timeout=600)  # fmt: skip
        if proc.returncode != 0:
            raise RuntimeError(f"imucal label: {proc.stderr.strip()}")
    return h5


def _transition(session, turn, accel_fn, gyro_fn) -> float:
    """Gravity-direction error (deg) after one rotation segment, predicted by the gyro from
    the still period before it (:func:`held_out`'s arithmetic)."""
    statics = session.static_segments()
    s0 = next(s for s in statics if s.stop == turn.start)
    s1 = next(s for s in statics if s.start == turn.stop)
    u0 = accel_fn(session.accel[s0.start : s0.stop]).mean(axis=0)
    u1 = accel_fn(session.accel[s1.start : s1.stop]).mean(axis=0)
    sl = slice(s0.stop - 1, s1.start + 1)
    R = integrate_rotations([session.time[sl]],
                            [gyro_fn(session.gyro[sl], accel_fn(session.accel[sl]))])[0]
    p = R.T @ (u0 / np.linalg.norm(u0))
    return float(np.degrees(np.arccos(np.clip(p @ u1 / np.linalg.norm(u1), -1, 1))))


def leave_one_out(h5: Path, mad: MadCal | None) -> dict:
    """Each of the labelled session's face-to-face transitions (its rotation segments, the
    known turns among them) left out of our calibration in turn and predicted (the default
    config, in process, its warnings ignored as --force would); MaD's calibration, whose fit
    uses none of them but its three turns, predicts them as it is. Also the known turns'
    angles as our full calibration integrates them."""
    from dataclasses import replace

    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config

    session = read_session(h5)
    full = calibrate_session(session, Config())
    ours, theirs, swapped, framed = [], [], [], []
    frame, to_theirs = None, None
    if mad is not None:  # the two accelerometers' gravity directions at every still period
        still = session.static_segments()
        mine, their = (_hold_directions(session, still, full.accel.apply),
                       _hold_directions(session, still, mad.accel))  # fmt: skip
        frame = accel_frames(mine, their)
        to_theirs, _ = Rotation.align_vectors(their, mine)
    for turn in session.rotation_segments():
        held = replace(session, segments=[s for s in session.segments if s is not turn])
        cal = calibrate_session(held, Config())
        gyro = lambda z, a, g=cal.gyro: g.apply(z, accel=a)  # noqa: E731
        ours.append(_transition(session, turn, cal.accel.apply, gyro))
        if mad is not None:
            theirs.append(_transition(session, turn, mad.accel, mad.gyro))
            swapped.append((_transition(session, turn, cal.accel.apply, mad.gyro),
                            _transition(session, turn, mad.accel, gyro)))  # fmt: skip
            turned = lambda z, c=cal.accel: to_theirs.apply(c.apply(z))  # noqa: E731
            framed.append(_transition(session, turn, turned, gyro))
    known = [r for r in full.gyro.rotations if r.known_angle_deg is not None]
    return {"ours": np.array(ours), "mad": np.array(theirs) if theirs else None,
            "swapped": np.array(swapped) if swapped else None, "frame": frame,
            "framed": np.array(framed) if framed else None,
            "frame_std": full.accel.rotation_std_deg,
            "known": [turn.angle_deg is not None for turn in session.rotation_segments()],
            "turns": [(r.label or r.segment, r.measured_angle_deg,
                       r.known_angle_deg, r.noise_deg) for r in known],
            "check": full.gyro.known_turn_check or KnownTurnCheck()}  # fmt: skip


def _hold_directions(session, still, accel_fn) -> np.ndarray:
    """Unit gravity direction of each still period as ``accel_fn`` calibrates it, (N, 3)."""
    u = np.array([accel_fn(session.accel[s.start : s.stop]).mean(axis=0) for s in still])
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def accel_frames(ours: np.ndarray, theirs: np.ndarray) -> tuple[float, float, float]:
    """How two accelerometer calibrations' gravity directions at the same still periods
    differ (unit vectors, (N, 3) each): the largest angle between them, the rotation that
    turns ours onto theirs best (least squares, Kabsch: a different frame, which moves every
    direction together and which the labels, not the data, choose), and the largest angle
    left after it (what the two fits disagree on within the frame), degrees."""
    def worst(a, b):  # atan2 of sine and cosine: exact near zero, where arccos is not
        sin = np.linalg.norm(np.cross(a, b), axis=1)
        return float(np.degrees(np.max(np.arctan2(sin, np.sum(a * b, axis=1)))))

    rot, _ = Rotation.align_vectors(theirs, ours)
    return worst(ours, theirs), float(np.degrees(rot.magnitude())), worst(rot.apply(ours),
                                                                          theirs)


def paired(ours: np.ndarray, theirs: np.ndarray) -> tuple[float, float]:
    """The mean paired difference of squared errors over the same transitions (our RMS^2
    minus theirs, deg^2) and its standard error: how far apart two calibrations are on these
    transitions, against what their number can tell (shown beside the verdict, which is the
    plain comparison of the two RMS)."""
    ours, theirs = np.asarray(ours, float), np.asarray(theirs, float)
    if ours.shape != theirs.shape:
        raise ValueError(f"{len(ours)} transitions against {len(theirs)} recorded")
    d = np.square(ours) - np.square(theirs)
    return float(np.mean(d)), float(np.std(d, ddof=1) / np.sqrt(len(d)))


def _loo_table(console, r: dict) -> bool:
    from rich.table import Table

    t = Table(title="MaD Lab Ferraris session (A) imported without its section list and "
                    "labelled with imucal label: each face-to-face transition left out in turn "
                    "(issue 24.5)")  # fmt: skip
    for col in ("quantity", "imucal", "MaD"):
        t.add_column(col, justify="right")
    ho = r["ours"]
    hm = np.asarray(MAD_LOO_DEG) if r["mad"] is None else r["mad"]

    def rms(v):
        return float(np.sqrt(np.mean(np.square(v))))

    t.add_row(f"held-out gravity direction, {len(ho)} transitions, RMS / max, deg "
              "(before: 1.42, then 0.694)", f"{rms(ho):.4f} / {ho.max():.3f}",
              f"{rms(hm):.4f} / {hm.max():.3f}")  # fmt: skip
    diff, se = paired(ho, hm)
    t.add_row("paired difference of squared errors, deg^2 (its standard error)",
              f"{diff:+.4f} ({se:.4f})", "-")  # fmt: skip
    moves = [i for i, known in enumerate(r["known"]) if not known]
    t.add_row(f"the {len(moves)} moves neither fit uses, RMS, deg", f"{rms(ho[moves]):.4f}",
              f"{rms(hm[moves]):.4f}")  # fmt: skip
    t.add_row("transitions predicted better (closer to the accelerometer's)",
              f"{int(np.sum(ho < hm))} of {len(ho)}", f"{int(np.sum(hm < ho))} of {len(ho)}")
    if r.get("swapped") is not None:  # whose accelerometer, whose gyro makes the difference
        sw = r["swapped"]
        t.add_row("our accelerometer with MaD's gyro; MaD's with ours, RMS, deg",
                  f"{rms(sw[:, 0]):.4f}; {rms(sw[:, 1]):.4f}", "-")  # fmt: skip
    if r.get("frame") is not None:
        worst, frame, within = r["frame"]
        fs = r.get("frame_std")  # per axis; a 3-D rotation of that std is sqrt(3) as large
        std = "" if fs is None else (f" (our frame's std {fs:.2g} per axis, "
                                     f"{fs * 3**0.5:.2g} in 3-D)")  # fmt: skip
        t.add_row("accelerometers' gravity at the still periods: largest angle apart; the "
                  "frame between them; apart within it, deg",
                  f"{worst:.3f}; {frame:.3f}{std}; {within:.3f}", "-")  # fmt: skip
    if r.get("framed") is not None:  # how much of the difference that frame makes
        t.add_row("ours, our accelerometer turned by that frame onto MaD's (each fit's frame "
                  "is the labels' within its std; the gyro's known turns are labelled), RMS, "
                  "deg", f"{rms(r['framed']):.4f}", "-")  # fmt: skip
    for name, measured, known, noise in r["turns"]:
        t.add_row(f"known turn {name}: integrated, deg (its std; before: y +3.8 off)",
                  f"{measured:+.2f} for {known:+.0f} ({noise:.2g})", "-")  # fmt: skip
    chk = r["check"]
    t.add_row("turns between still periods", str(chk.turns_between_still_periods),
              "not used")  # fmt: skip
    t.caption = (f"MaD's fit uses the {len(ho) - len(moves)} known turns among the "
                 f"{len(ho)} transitions; ours leaves each out in turn")  # fmt: skip
    if r["mad"] is None:  # MaD's package not installed: its figures as measured here with it
        t.caption += ("; MaD's figures recorded with imucal (MaD Lab) 2.6.0 (pip install -e "
                      "'.\\[bench]' measures them again)")  # fmt: skip
    console.print(t)
    within = all(abs(m - k) <= 2 * n for _, m, k, n in r["turns"])
    return within and rms(ho) <= rms(hm)


def run(console) -> bool:
    """Print the tables; True when our held-out error is no worse than MaD's (where both ran)."""
    from rich.table import Table

    if not DATA.is_dir():
        console.print(f"mad: {DATA} not found: skipped")
        return True
    ok = True
    with tempfile.TemporaryDirectory() as tmp:
        results = [compare(n, Path(tmp)) for n in SESSIONS]
        loo = leave_one_out(labelled_session(Path(tmp)), _mad("A"))
    for r in results:
        t = Table(title=f"MaD Lab Ferraris session ({r['session']}): imucal beside "
                        f"{r['mad_source'] or 'MaD (not available)'}")  # fmt: skip
        for col in ("quantity", "imucal", "MaD"):
            t.add_column(col, justify="right")
        o, m = r.get("ours", {}), r.get("mad", {})

        def fmt(v, f="{:.4g}"):
            return "-" if v is None else " ".join(f.format(x) for x in v)

        t.add_row("gyro solver", str(r["ours_solver"]), "Ferraris (eqs. 9-15)")
        t.add_row("gyro gain x y z, raw per deg/s", fmt(o.get("gyro_gain")),
                  fmt(m.get("gyro_gain")))  # fmt: skip
        t.add_row("  its std", fmt(o.get("gyro_gain_std"), "{:.2g}"), "not stated")
        t.add_row("gyro bias, raw", fmt(o.get("gyro_bias")), fmt(m.get("gyro_bias")))
        t.add_row("gyro axes xy xz yz minus 90, deg", fmt(o.get("gyro_axes_deg"), "{:+.2f}"),
                  fmt(m.get("gyro_axes_deg"), "{:+.2f}"))  # fmt: skip
        t.add_row("rate std (worst direction)", "-" if o.get("rate_std") is None else
                  f"{100 * o['rate_std']:.2g} %", "not stated")  # fmt: skip
        ho, hm = r.get("ours_held_out"), r.get("mad_held_out")
        if ho:
            t.add_row("held-out gravity direction after the face-to-face moves, RMS / max, deg",
                      f"{np.sqrt(np.mean(np.square(ho))):.3f} / {np.max(ho):.3f}",
                      "-" if not hm else
                      f"{np.sqrt(np.mean(np.square(hm))):.3f} / {np.max(hm):.3f}")  # fmt: skip
            if hm:
                ok = ok and np.sqrt(np.mean(np.square(ho))) <= np.sqrt(np.mean(np.square(hm)))
        elif r["no_held_out"]:  # nothing to compare fairly: said, not a pass or a fail
            t.add_row("held-out gravity direction after the face-to-face moves", "-", "-")
            t.caption = r["no_held_out"]
        if r["ours_note"]:
            t.caption = "; ".join(x for x in (t.caption, r["ours_note"]) if x)
        console.print(t)
    loo_ok = _loo_table(console, loo)
    console.print("mad, labelled session: " + ("[green]PASS[/]" if loo_ok else "[red]FAIL[/]")
                  + " (held-out transitions no worse than MaD's; known turns within 2 std)")
    compared = [r["session"] for r in results if r.get("ours_held_out") and r.get("mad_held_out")]
    if not compared:
        console.print("mad: no session with held-out moves for both: nothing compared")
        return loo_ok
    on = f" on session{'s' if len(compared) > 1 else ''} {', '.join(compared)}"
    verdict = (f"[green]PASS[/] (held-out error no worse than MaD's{on})" if ok
               else f"[red]FAIL[/] (held-out error worse than MaD's{on})")  # fmt: skip
    console.print("mad, section list: " + verdict)
    return bool(ok and loo_ok)
