"""Issue 28.1: sessions with several IMUs (spec "Several IMUs"): ``/imus/<name>`` groups and the
root attribute ``imus`` written and read, each IMU's own time stamps kept, bad files refused
with one line; the simulated set (``simulate --imus``) and its truth."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from imucal_cli.errors import InputError, SessionError
from imucal_cli.formats.session import (
    ImuLayout,
    ImuStream,
    Segment,
    Session,
    SessionWriter,
    imu_session,
    map_segments,
    read_session,
    set_names,
    write_session,
)
from imucal_cli.simulate.imu_set import simulate_set

CREATED = "2026-01-01T00:00:00Z"


@pytest.fixture(scope="module")
def set3():
    return simulate_set(3, seed=4, created=CREATED)


def test_round_trip_keeps_every_imu_as_sent(set3, tmp_path):
    session, _ = set3
    path = tmp_path / "set.h5"
    write_session(path, session)
    back = read_session(path)
    assert set_names(back) == ["reference", "imu1", "imu2"]
    for name, imu in session.imus.items():
        got = back.imus[name]
        for field in ("time", "accel", "gyro"):
            assert np.array_equal(getattr(got, field), getattr(imu, field)), (name, field)
        assert got.sample_rate_hz == imu.sample_rate_hz
        assert got.accel_units == imu.accel_units == "counts"
        assert got.sensor == imu.sensor
    assert np.array_equal(back.time, session.time)
    assert back.segments == session.segments
    with h5py.File(path, "r") as f:  # the spec's layout, as any HDF5 reader sees it
        assert [x.decode() if isinstance(x, bytes) else x for x in f.attrs["imus"]] == \
            ["reference", "imu1", "imu2"]
        assert set(f["imus"]) == {"imu1", "imu2"}
        assert f["imus/imu1/time"].shape == (len(session.imus["imu1"].time),)
        assert f["imus/imu2"].attrs["sample_rate_hz"] == session.imus["imu2"].sample_rate_hz


def test_each_imu_keeps_its_own_rate_and_stamps(set3):
    session, truth = set3
    rates = {n: 1 / np.median(np.diff(i.time)) for n, i in session.imus.items()}
    for name, imu in session.imus.items():
        assert rates[name] == pytest.approx(imu.sample_rate_hz, rel=1e-6)
        assert not np.array_equal(imu.time[: len(session.time)], session.time[: len(imu.time)])
    offsets = [truth.to_dict()["imus"][n]["time_offset_s"] for n in session.imus]
    assert all(abs(o) <= 0.010 for o in offsets) and len(set(offsets)) == 2
    angles = [truth.to_dict()["imus"][n]["rotation_deg"] for n in session.imus]
    assert all(0 < a <= 5.0 for a in angles)


def test_one_imu_session_has_no_imus_attribute(tmp_path):
    session, _ = simulate_set(1, seed=2, created=CREATED)
    assert session.imus == {}
    write_session(tmp_path / "one.h5", session)
    with h5py.File(tmp_path / "one.h5", "r") as f:
        assert "imus" not in f.attrs and "imus" not in f
    assert read_session(tmp_path / "one.h5").imus == {}


def test_simulated_set_is_reproducible_and_the_reference_is_the_seeds_part():
    a, ta = simulate_set(2, seed=9, created=CREATED)
    b, _ = simulate_set(2, seed=9, created=CREATED)
    assert np.array_equal(a.imus["imu1"].accel, b.imus["imu1"].accel)
    from imucal_cli.simulate.triad import simulate

    _, single = simulate(plan="random:18", seed=9, created=CREATED)
    assert np.array_equal(ta.accel.matrix, single.accel.matrix)  # one seed, one part


def test_map_segments_by_time():
    ref_t = np.arange(100) * 0.01
    segs = [Segment("0000", "static", 10, 30), Segment("0001", "rotation", 30, 50)]
    t = np.arange(400) * 0.0025 + 0.001  # 400 Hz, another phase
    mapped = map_segments(segs, ref_t, t)
    for seg, m in zip(segs, mapped, strict=True):
        assert t[m.start] >= ref_t[seg.start] and t[m.start - 1] < ref_t[seg.start]
        assert t[m.stop - 1] <= ref_t[seg.stop - 1] < t[m.stop]
    shifted = map_segments(segs, ref_t, t, offset_s=0.05)
    assert shifted[0].start == mapped[0].start - 20


def test_imu_session_is_a_single_imu_session(set3):
    session, _ = set3
    sub = imu_session(session, "imu2")
    assert sub.imus == {} and sub.reference_name == "imu2"
    assert sub.time is session.imus["imu2"].time
    assert [s.name for s in sub.segments] == [s.name for s in session.segments]
    with pytest.raises(SessionError, match="no IMU 'imu9'"):
        imu_session(session, "imu9")


def _two(tmp_path, mutate):
    session, _ = simulate_set(2, seed=1, created=CREATED, hold_s=0.5, plan="six")
    path = tmp_path / "bad.h5"
    write_session(path, session)
    with h5py.File(path, "r+") as f:
        mutate(f)
    return path


@pytest.mark.parametrize("mutate, message", [
    (lambda f: f["imus/imu1/time"].__setitem__(5, 0.0), "/imus/imu1/time is not strictly"),
    (lambda f: f.attrs.__setitem__("imus", np.array(["reference", "imu1", "imu7"],
                                                    dtype=h5py.string_dtype())),
     "/imus/imu7 is missing"),
    (lambda f: f.attrs.__setitem__("imus", np.array(["reference", "reference"],
                                                    dtype=h5py.string_dtype())),
     "names 'reference' twice"),
    (lambda f: (f["imus/imu1"].__delitem__("accel"),
                f["imus/imu1"].create_dataset("accel", data=np.zeros((3, 2)))),
     r"/imus/imu1/accel must have shape"),
    (lambda f: f["imus/imu1"].attrs.__setitem__("sample_rate_hz", -3.0),
     "sample_rate_hz' must be a positive number"),
    # as /raw's (audit): an OverflowError traceback in calibrate; stamps in another unit
    (lambda f: f["imus/imu1/accel"].__setitem__(slice(None), f["imus/imu1/accel"][()] * 1e300),
     "/imus/imu1/accel reads .* beyond any sensor"),
    (lambda f: f["imus/imu1/time"].__setitem__(slice(None), f["imus/imu1/time"][()] * 1e12),
     "/imus/imu1/time steps .* slower than any IMU"),
])  # fmt: skip
def test_bad_imus_are_refused_with_one_line(tmp_path, mutate, message):
    path = _two(tmp_path, mutate)
    with pytest.raises(SessionError, match=message) as err:
        read_session(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value)


def _unlisted(f: h5py.File, listed: list[str] | None) -> None:
    """The root attribute ``imus`` set to ``listed`` (None: deleted), the groups left."""
    if listed is None:
        del f.attrs["imus"]
    else:
        f.attrs["imus"] = np.array(listed, dtype=h5py.string_dtype())


@pytest.mark.parametrize(("listed", "said"), [
    (None, "has no root attribute 'imus'"),
    (["reference"], "lists only reference in its root attribute 'imus'"),
])  # fmt: skip
def test_groups_the_root_attribute_does_not_list_are_refused(tmp_path, listed, said):
    """The spec: "The root attribute ``imus`` lists every IMU's name": a group of /imus it does
    not name is a file contradicting itself, refused by every reader (read_session for
    calibrate, report, export, label; open_samples for noise and apply)."""
    from imucal_cli.formats.session import open_samples

    path = _two(tmp_path, lambda f: _unlisted(f, listed))
    for read in (read_session, open_samples):
        with pytest.raises(SessionError, match="/imus holds imu1 but the file") as err:
            read(path)
        assert said in str(err.value) and "\n" not in str(err.value)


def test_writer_appends_each_imu_at_its_own_times(tmp_path):
    path = tmp_path / "live.h5"
    layout = ImuLayout(accel=3, gyro=3, attrs={"sample_rate_hz": 200.0, "sensor": "B"})
    with SessionWriter(path, imus={"imu1": layout}, reference_name="A") as w:
        for block in range(3):
            t = block + np.arange(100) / 100
            w.append(t, np.ones((100, 3)), np.zeros((100, 3)))
            t2 = block + 0.003 + np.arange(200) / 200
            w.append_imu("imu1", t2, accel=np.full((200, 3), 2.0), gyro=np.zeros((200, 3)))
        with pytest.raises(SessionError, match="not finite and strictly increasing"):
            w.append_imu("imu1", [0.5], accel=np.ones((1, 3)), gyro=np.ones((1, 3)))
        with pytest.raises(SessionError, match="no IMU 'imu2'"):
            w.append_imu("imu2", [9.0], accel=np.ones((1, 3)), gyro=np.ones((1, 3)))
        w.add_segment("static", 0, 100)
    back = read_session(path)
    assert back.reference_name == "A" and list(back.imus) == ["imu1"]
    assert len(back.imus["imu1"].time) == 600 and np.all(back.imus["imu1"].accel == 2.0)
    assert back.imus["imu1"].sensor == "B"


def test_a_set_is_continued_with_the_same_imus_only(tmp_path, set3):
    """``reopen`` continues every IMU's datasets from its own last sample (the capture's
    IMUs must be the session's: names and channels, refused otherwise, the file unchanged)."""
    path = tmp_path / "set.h5"
    write_session(path, set3[0])
    before, old = path.read_bytes(), read_session(path)
    layouts = {n: ImuLayout.of(s) for n, s in old.imus.items()}
    with pytest.raises(InputError, match="holds the IMUs imu1, imu2 .* this capture none"):
        SessionWriter.reopen(path)
    with pytest.raises(InputError, match="this capture imu1:"):
        SessionWriter.reopen(path, imus={"imu1": layouts["imu1"]})
    narrow = {**layouts, "imu2": ImuLayout(accel=3, gyro=None)}
    with pytest.raises(InputError, match="IMU imu2 records accel 3, gyro 3"):
        SessionWriter.reopen(path, imus=narrow)
    assert path.read_bytes() == before
    w = SessionWriter.reopen(path, imus=layouts)
    assert w.imu_counts() == {n: len(s.time) for n, s in old.imus.items()}
    t0 = max(old.time[-1], *(s.time[-1] for s in old.imus.values())) + 1.0
    w.append(t0 + np.arange(5) / 100, np.zeros((5, 3)), np.zeros((5, 3)))
    for name in layouts:
        w.append_imu(name, t0 + np.arange(4) / 80, accel=np.ones((4, 3)), gyro=np.ones((4, 3)))
    with pytest.raises(SessionError, match="imu1: time is not finite and strictly"):
        w.append_imu("imu1", [t0], accel=np.ones((1, 3)), gyro=np.ones((1, 3)))
    w.close()
    back = read_session(path)
    assert len(back.time) == len(old.time) + 5
    for name, imu in back.imus.items():
        n = len(old.imus[name].time)
        assert len(imu.time) == n + 4 and np.all(np.diff(imu.time) > 0)
        np.testing.assert_array_equal(imu.accel[:n], old.imus[name].accel)
        assert np.all(imu.accel[n:] == 1.0)


def test_session_model_defaults_keep_one_imu():
    s = Session(time=np.arange(3.0), accel=None, gyro=None, temperature=None, segments=[],
                created=CREATED)  # fmt: skip
    assert s.imus == {} and set_names(s) == ["reference"]
    assert ImuStream(time=np.arange(2.0)).channels().keys() == {"time"}


def test_retime_moves_the_other_imus_with_the_reference(tmp_path):
    """``retime`` of ``/raw``'s samples 100-199 (host stamps known better later) moves the
    other IMU's times with them: where it sampled between two reference samples it stays
    between them, in the same proportion; before and after the re-timed run nothing moves
    (past the last, it follows the last); samples not written yet are refused."""
    path = tmp_path / "re.h5"
    layout = ImuLayout(accel=3, gyro=3, attrs={"sample_rate_hz": 200.0})
    with SessionWriter(path, imus={"imu1": layout}) as w:
        t = np.arange(300) / 100
        w.append(t, np.ones((300, 3)), np.zeros((300, 3)))
        t2 = 0.003 + np.arange(600) / 200
        w.append_imu("imu1", t2, accel=np.ones((600, 3)), gyro=np.zeros((600, 3)))
        w.flush()
        w.append_imu("imu1", [3.5], accel=np.ones((1, 3)), gyro=np.zeros((1, 3)))
        with pytest.raises(SessionError, match="not written yet"):
            w.retime(100, t[100:200] + 0.002)
        w.flush()
        w.retime(100, t[100:200] + 0.002)
    t2 = np.r_[t2, 3.5]
    back = read_session(path)
    moved = back.imus["imu1"].time - t2
    inside = (t2 >= t[100]) & (t2 <= t[199])
    np.testing.assert_allclose(moved[inside], 0.002, atol=1e-12)
    np.testing.assert_allclose(moved[t2 < t[99]], 0.0, atol=1e-12)
    np.testing.assert_allclose(moved[t2 > t[200]], 0.0, atol=1e-12)
    assert np.all(np.diff(back.imus["imu1"].time) > 0)
