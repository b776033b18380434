"""solvers/rotation.py (numpy rotations) against scipy.spatial.transform.Rotation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation as SciRotation

from imucal_cli.solvers.rotation import Rotation


def _rotvecs(rng, n=200):
    """Random rotation vectors, including tiny angles and angles near pi."""
    axes = rng.standard_normal((n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([rng.uniform(0, np.pi, n - 6), [0, 1e-9, 1e-5, 1e-3, np.pi - 1e-7,
                                                             np.pi - 1e-3]])  # fmt: skip
    return axes * angles[:, None]


def test_rotvec_and_matrix_round_trips_match_scipy():
    rng = np.random.default_rng(0)
    v = _rotvecs(rng)
    np.testing.assert_allclose(Rotation.from_rotvec(v).as_matrix(),
                               SciRotation.from_rotvec(v).as_matrix(), atol=1e-14)  # fmt: skip
    m = SciRotation.from_rotvec(v).as_matrix()
    ours, ref = Rotation.from_matrix(m).as_rotvec(), SciRotation.from_matrix(m).as_rotvec()
    np.testing.assert_allclose(ours[:-2], ref[:-2], atol=1e-12)
    # near pi the axis sign is ambiguous: same rotation
    np.testing.assert_allclose(Rotation.from_rotvec(ours[-2:]).as_matrix(), m[-2:], atol=1e-12)
    for k in (0, 5, 197):  # single rotations keep their shape
        assert Rotation.from_rotvec(v[k]).as_matrix().shape == (3, 3)
        ref_k = SciRotation.from_matrix(m[k]).as_rotvec()
        np.testing.assert_allclose(Rotation.from_matrix(m[k]).as_rotvec(), ref_k, atol=1e-12)
    ref_q = SciRotation.from_matrix(m).as_quat(canonical=True)
    np.testing.assert_allclose(Rotation.from_matrix(m).as_quat(), ref_q, atol=1e-12)


def test_non_orthogonal_matrix_is_projected_like_scipy():
    rng = np.random.default_rng(1)
    m = SciRotation.random(5, random_state=rng).as_matrix() + 1e-3 * rng.standard_normal((5, 3, 3))
    np.testing.assert_allclose(Rotation.from_matrix(m).as_matrix(),
                               SciRotation.from_matrix(m).as_matrix(), atol=1e-9)  # fmt: skip


def test_composition_inverse_apply():
    rng = np.random.default_rng(2)
    p, q = _rotvecs(rng, 8)[:2]
    ours = (Rotation.from_rotvec(p) * Rotation.from_rotvec(q)).as_rotvec()
    ref = (SciRotation.from_rotvec(p) * SciRotation.from_rotvec(q)).as_rotvec()
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    x = rng.standard_normal((4, 3))
    np.testing.assert_allclose(Rotation.from_rotvec(p).inv().apply(x),
                               SciRotation.from_rotvec(p).inv().apply(x), atol=1e-12)  # fmt: skip


@pytest.mark.parametrize("n, weighted", [(1, False), (2, False), (10, True), (10, False)])
def test_align_vectors_matches_scipy(n, weighted):
    rng = np.random.default_rng(3 + n)
    b = rng.standard_normal((n, 3))
    R = SciRotation.random(random_state=rng)
    a = R.apply(b) + 0.01 * rng.standard_normal((n, 3))
    w = rng.uniform(0.5, 2, n) if weighted else None
    ours, rssd = Rotation.align_vectors(a, b, weights=w)
    ref, rssd_ref = SciRotation.align_vectors(a, b, weights=w)
    np.testing.assert_allclose(ours.as_matrix(), ref.as_matrix(), atol=1e-10)
    if n > 1:
        assert rssd == pytest.approx(rssd_ref, rel=1e-9, abs=1e-12)
    # antiparallel single pair: a half turn taking b onto a
    r, _ = Rotation.align_vectors([[0, 0, -1.0]], [[0, 0, 1.0]])
    np.testing.assert_allclose(r.apply([0, 0, 1.0]), [0, 0, -1.0], atol=1e-12)


def test_align_vectors_with_a_primary_pair_matches_scipy():
    rng = np.random.default_rng(11)
    b = rng.standard_normal((5, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    a = SciRotation.random(random_state=rng).apply(b) + 0.05 * rng.standard_normal((5, 3))
    w = np.array([np.inf, 1.0, 2.0, 0.5, 1.0])
    ours, rssd = Rotation.align_vectors(a, b, weights=w)
    ref, rssd_ref = SciRotation.align_vectors(a, b, weights=w)
    np.testing.assert_allclose(ours.as_matrix(), ref.as_matrix(), atol=1e-10)
    assert rssd == pytest.approx(rssd_ref, rel=1e-9)
    # the primary pair is aligned exactly
    p = ours.apply(b[0])
    np.testing.assert_allclose(p / np.linalg.norm(p), a[0] / np.linalg.norm(a[0]), atol=1e-12)
