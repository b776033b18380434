"""The labelled solver's placement in two parts (issue 24.5): a face's own deviation, shared by
every pose held on that face, and each hold's (the table's tilt at its heading, how it sat).

MaD Lab's Ferraris session holds +X, +Y and +Z up three or four times each: its repeats of a
face agree to about 0.03 deg where the faces sit 0.1-0.3 deg off their labels. Taken as
independent placements, the four +X poses count four times against the single -X, and the
fit's 95 % intervals held the truth in 73 % of simulated sessions of that design; with the
face's part shared, 93-97 %. Designs whose labels are all different (six, qureshi18) keep the
single placement, bit for bit.

The sessions here are drawn directly from the model (L1b, L2): a part of given sensitivity
and bias, each face's normal off its label by ``face_deg`` RMS, each hold off its face by
``hold_deg`` RMS, the pose means with the noise of 400 samples.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from imucal_cli.estimators.accel.labelled import fit_labelled, public_params
from imucal_cli.estimators.accel.labelled_model import faces_of, sphere_exp, tangent_bases

G0 = 9.80665
FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
#: Each pose's face (an index into FACES), as MaD Lab's session A holds them: +X four times,
#: +Y and +Z three times (before and after their 360-degree turns), the others once.
MAD_DESIGN = [0, 0, 1, 2, 3, 4, 5, 0, 0, 2, 2, 4, 4]
SIX = [0, 1, 2, 3, 4, 5]


def draw(seed: int, design, face_deg: float, hold_deg: float, noise=0.01, samples=400):
    """Pose means, labels, their covariance and the true parameters of one session."""
    rng = np.random.default_rng(seed)
    S = np.diag(rng.uniform(800, 860, 3)) + rng.normal(0, 8, (3, 3))  # counts per m/s^2
    B = rng.normal(0, 50, 3)
    up = FACES[design]
    face = rng.normal(0, np.radians(face_deg) / np.sqrt(2), (len(FACES), 2))
    hold = rng.normal(0, np.radians(hold_deg) / np.sqrt(2), (len(design), 2))
    u, _ = sphere_exp(up, tangent_bases(up), face[design] + hold)
    cov = noise**2 * S @ S.T / samples
    a = B + G0 * u @ S.T + rng.standard_normal((len(design), 3)) @ np.linalg.cholesky(cov).T
    return a, up, np.repeat(cov[None], len(design), axis=0), public_params(B, S)


def coverage(design, seeds, face_deg, hold_deg) -> tuple[np.ndarray, np.ndarray]:
    """Whether each parameter's 95 % interval holds the truth, (seeds, 12), and the two
    parts of the placement estimated, (seeds, 2) degrees (NaN where not split)."""
    hits, parts = [], []
    for seed in seeds:
        a, up, cov, truth = draw(seed, design, face_deg, hold_deg)
        res = fit_labelled(a, up, G0, cov, noise_dof=1e4)
        hits.append(np.abs(res.params - truth) <= res.ci95)
        parts.append([np.nan if p is None else p
                      for p in (res.placement_face_deg, res.placement_hold_deg)])  # fmt: skip
    return np.array(hits), np.array(parts)


def test_faces_are_the_labels():
    up = np.array([[1, 0, 0], [0, 1, 0], [1, 0, 0], [np.nan] * 3, [0, 1, 0.0]])
    f = faces_of(up)
    assert f[0] == f[2] and f[1] == f[4] and len(set(f.tolist())) == 3


def test_a_face_held_again_shares_its_placement():
    """Both parts estimated (the face's 0.3 deg, the hold's 0.08: the medians over 30
    sessions, each part from few equations, six faces for the face's), and the intervals hold
    the truth where independent placements held it 73 % of the time (360 intervals: binomial
    std 1.3 % at 93 %)."""
    a, up, cov, _ = draw(1, MAD_DESIGN, 0.3, 0.08)
    res = fit_labelled(a, up, G0, cov, noise_dof=1e4)
    assert res.placement_deg == pytest.approx(np.hypot(res.placement_face_deg,
                                                       res.placement_hold_deg))  # fmt: skip
    hits, parts = coverage(MAD_DESIGN, range(30), 0.3, 0.08)
    face, hold = np.median(parts, axis=0)
    assert 0.15 < face < 0.45 and 0.05 < hold < 0.12, (face, hold)
    assert hits.mean() > 0.88, hits.mean(axis=0)


def test_distinct_labels_keep_one_placement():
    """Six faces: no face holds two poses, the placement is not split (one part, as before)."""
    a, up, cov, _ = draw(1, SIX, 0.0, 2.0)
    res = fit_labelled(a, up, G0, cov, noise_dof=1e4)
    assert res.placement_face_deg is None and res.placement_hold_deg is None
    assert res.placement_source == "estimated" and 0.5 < res.placement_deg < 5


@pytest.mark.slow
@pytest.mark.parametrize("design, face_deg, hold_deg", [
    (MAD_DESIGN, 0.3, 0.08),  # MaD Lab's session: faces off their labels, holds repeatable
    (MAD_DESIGN, 1.5, 1.5),   # both parts alike
    (MAD_DESIGN, 0.0, 2.0),   # every hold placed on its own (the simulator's placement)
])  # fmt: skip
def test_intervals_cover_the_truth_over_200_sessions(design, face_deg, hold_deg):
    """93-97 % of the 95 % intervals hold the truth (2,400 intervals: binomial std 0.45 %)."""
    hits, _ = coverage(design, range(200), face_deg, hold_deg)
    assert 0.93 <= hits.mean() <= 0.97, hits.mean(axis=0)


DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "imucal_ferraris"


@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason="MaD Lab's Ferraris recordings are absent")
def test_mad_lab_session_repeats_agree_within_their_face(tmp_path):
    """Session A labelled as a user labels it: its faces sit off their labels by more than
    its repeats of a face differ, and the placement is split accordingly."""
    from bench.mad import labelled_session
    from imucal_cli.calibrate.session import calibrate_session
    from imucal_cli.formats.config import Config
    from imucal_cli.formats.session import read_session

    cal = calibrate_session(read_session(labelled_session(tmp_path)), Config())
    placement = cal.accel.to_dict()["placement"]
    assert placement["face_deg"] > 1.5 * placement["hold_deg"], placement
    assert placement["rms_deg"] < 0.5
