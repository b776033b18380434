"""Issue 28.3 (exports and apply per IMU): a set's calibration exported where the target holds
several IMUs (PX4 CAL_ACC0..3, ArduPilot INS_ACC/ACC2/ACC3, a Kalibr and an OpenVINS IMU chain
with T_i_b and time_offset), read back by the readers (pymavlink's parameter loader, YAML), and
applied per IMU in its own frame or the reference's."""

from __future__ import annotations

import dataclasses
import json

import h5py
import numpy as np
import pytest

from imucal_cli.calibrate.common import static_poses
from imucal_cli.calibrate.imu_set import calibrate_set
from imucal_cli.errors import InputError
from imucal_cli.formats.calibration import write_calibration
from imucal_cli.formats.config import Config
from imucal_cli.formats.exporters import ExportOptions
from imucal_cli.formats.session import imu_session, write_session
from imucal_cli.simulate.imu_set import simulate_set
from imucal_cli.use.export import export
from imucal_cli.use.export_set import pick_imu

from .cli_helpers import assert_one_line_error, run
from .test_export_targets import kalibr_yaml, noise, px4_params  # noqa: F401

CREATED = "2026-01-01T00:00:00Z"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A set of 3 IMUs in SI raw units (the drivers' m/s^2 and rad/s), calibrated."""
    session, truth = simulate_set(3, seed=8, units="m/s^2", created=CREATED)
    cal = calibrate_set(session, Config(), name="set.h5")
    folder = tmp_path_factory.mktemp("set")
    write_session(folder / "set.h5", session)
    write_calibration(folder / "set.cal.json", cal)
    return session, cal, folder


def test_ardupilot_parameters_per_imu_read_by_pymavlink(calibrated, tmp_path):
    from pymavlink import mavparm

    session, cal, _ = calibrated
    path = tmp_path / "set.parm"
    path.write_text(export(cal, "ardupilot"))
    params = mavparm.MAVParmDict()
    assert params.load(str(path), use_excludes=False)
    for n, name in ((1, "reference"), (2, "imu1"), (3, "imu2")):
        one = {k: float(v) for k, v in (ln.split(",") for ln in
               export(pick_imu(cal, name), "ardupilot").splitlines() if not ln.startswith("#"))}
        acc = "INS_ACC" if n == 1 else f"INS_ACC{n}"
        gyr = "INS_GYR" if n == 1 else f"INS_GYR{n}"
        for axis in "XYZ":
            assert params[f"{acc}OFFS_{axis}"] == pytest.approx(one[f"INS_ACCOFFS_{axis}"])
            assert params[f"{acc}SCAL_{axis}"] == pytest.approx(one[f"INS_ACCSCAL_{axis}"])
            assert params[f"{gyr}OFFS_{axis}"] == pytest.approx(one[f"INS_GYROFFS_{axis}"])


def test_px4_parameters_per_imu(calibrated):
    _, cal, _ = calibrated
    text = export(cal, "px4")
    p = px4_params(text)
    for k, name in enumerate(("reference", "imu1", "imu2")):
        one = px4_params(export(pick_imu(cal, name), "px4"))
        for axis in "XYZ":
            assert p[f"CAL_ACC{k}_{axis}OFF"] == one[f"CAL_ACC0_{axis}OFF"]
            assert p[f"CAL_ACC{k}_{axis}SCALE"] == one[f"CAL_ACC0_{axis}SCALE"]
            assert p[f"CAL_GYRO{k}_{axis}OFF"] == one[f"CAL_GYRO0_{axis}OFF"]
    assert "[imu1] in CAL_ACC1_*, CAL_GYRO1_*; measured" in text
    assert "[imu2] CAL_ACC2_ID / CAL_GYRO2_ID (and TC_A2_ID / TC_G2_ID) not written" in text
    with pytest.raises(InputError, match="--device-id N names one device"):
        export(cal, "px4", options=ExportOptions(device_id=3))


def test_px4_set_each_imu_at_its_instance_with_its_own_device_id(calibrated):
    """``--device-id NAME=N`` (repeated or comma-separated): each IMU's values and its own id
    at its instance, CAL_ACCn_ID = CAL_GYROn_ID = the id given for IMU n (PX4 finds a sensor's
    calibration by its device id over CAL_ACC0..3_ID); an id of 2^31 or more as PX4's int32."""
    _, cal, folder = calibrated
    ids = {"reference": 2818058, "imu1": 3014666, "imu2": 4294967000}
    proc = run("export", folder / "set.cal.json", "-f", "px4", "--device-id",
               "reference=2818058,imu1=3014666", "--device-id", "imu2=4294967000")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    p = px4_params(proc.stdout)
    for k, name in enumerate(ids):
        for sensor in ("ACC", "GYRO"):
            assert p[f"CAL_{sensor}{k}_ID"] % (1 << 32) == ids[name]
        one = px4_params(export(pick_imu(cal, name), "px4"))
        for axis in "XYZ":
            assert p[f"CAL_ACC{k}_{axis}OFF"] == one[f"CAL_ACC0_{axis}OFF"]
            assert p[f"CAL_GYRO{k}_{axis}OFF"] == one[f"CAL_GYRO0_{axis}OFF"]
    assert p["CAL_ACC2_ID"] == 4294967000 - (1 << 32)  # int32, as PX4 stores it
    assert not any(n.startswith(("CAL_ACC3", "CAL_GYRO3")) for n in p)
    # One IMU's id alone: the others' _ID left out, and the file says which option sets them.
    proc = run("export", folder / "set.cal.json", "-f", "px4", "--device-id", "imu1=77")
    p = px4_params(proc.stdout)
    assert p["CAL_ACC1_ID"] == p["CAL_GYRO1_ID"] == 77
    assert "CAL_ACC0_ID" not in p and "CAL_ACC2_ID" not in p
    assert "(no --device-id reference=N)" in proc.stdout
    assert "[imu2] CAL_ACC2_ID / CAL_GYRO2_ID (and TC_A2_ID / TC_G2_ID) not written (no " \
        "--device-id imu2=N)" in proc.stdout  # fmt: skip
    # --imu NAME picks that IMU's id among those given, at instance 0.
    proc = run("export", folder / "set.cal.json", "-f", "px4", "--imu", "imu1",
               "--device-id", "imu1=77,imu2=78")  # fmt: skip
    p = px4_params(proc.stdout)
    assert p["CAL_ACC0_ID"] == p["CAL_GYRO0_ID"] == 77 and "CAL_ACC1_ID" not in p
    assert p["CAL_ACC0_XOFF"] == px4_params(export(pick_imu(cal, "imu1"), "px4"))["CAL_ACC0_XOFF"]
    # ArduPilot's set takes the same ids (INS_ACC2_ID for the second IMU).
    proc = run("export", folder / "set.cal.json", "-f", "ardupilot", "--device-id",
               "reference=11,imu1=12")  # fmt: skip
    parm = dict(ln.split(",") for ln in proc.stdout.splitlines() if not ln.startswith("#"))
    assert (parm["INS_ACC_ID"], parm["INS_ACC2_ID"], parm["INS_GYR2_ID"]) == ("11", "12", "12")
    assert "INS_ACC3_ID" not in parm


@pytest.mark.parametrize("args, words", [
    (["--device-id", "imu9=5"], ["--device-id imu9=5: the calibration's IMUs are reference, "
                                 "imu1, imu2"]),
    (["--device-id", "5"], ["--device-id N names one device", "imu1=N"]),
    (["--device-id", "imu1=5,imu1=6"], ["IMU imu1 given twice"]),
    (["--device-id", "reference=5", "--device-id", "7"], ["not both"]),
    (["--device-id", "imu1=0"], ["non-zero 32-bit integer"]),
    (["--device-id", "imu1=abc"], ["non-zero 32-bit integer"]),
    (["--device-id", "=5"], ["no IMU name before '='"]),
    (["--imu", "imu7", "--device-id", "imu1=5"], ["--imu imu7: the calibration's IMUs are"]),
])  # fmt: skip
def test_px4_set_device_id_refusals(calibrated, args, words):
    _, _, folder = calibrated
    assert_one_line_error(run("export", folder / "set.cal.json", "-f", "px4", *args), *words)


def _still_means(session, cal, name):
    """Each shared pose's mean raw accel (the driver's m/s^2) of IMU ``name``."""
    entry = cal.to_dict()["imus"].get(name, {})
    sub = imu_session(session, name, entry.get("set", {}).get("coarse_offset_s", 0.0))
    poses = static_poses(sub)
    return {s.name: poses.a_mean[k] for k, s in enumerate(poses.segments)}


@pytest.mark.parametrize("fmt", ["kalibr", "openvins"])
def test_imu_chain_puts_each_imu_where_the_reference_sees_it(calibrated, fmt, noise):  # noqa: F811
    """Read back with YAML, the chain's numbers reproduce each IMU's still readings from the
    reference's: a_i = T_i_b a_b, each IMU calibrated with its own intrinsics as the target's
    model says (Kalibr: inv(M_accel) (p - b); OpenVINS: the same with R_IMUtoACC = I)."""
    session, cal, _ = calibrated
    opts = ExportOptions(noise=noise)
    chain = kalibr_yaml(export(cal, fmt, options=opts))
    assert list(chain) == ["imu0", "imu1", "imu2"]
    assert chain["imu1"]["rostopic"] == "/imu1"

    def own(block, p):
        M = np.array(block["accelerometers"]["M"] if fmt == "kalibr" else block["Ta"])
        return np.linalg.solve(M, p - np.array(block["accelerometer_bias"]))

    ref = _still_means(session, cal, "reference")
    for k, name in ((1, "imu1"), (2, "imu2")):
        block = chain[f"imu{k}"]
        assert block["time_offset"] == pytest.approx(cal.to_dict()["imus"][name]["time_offset_s"])
        T_k, T_0 = np.array(block["T_i_b"]), np.array(chain["imu0"]["T_i_b"])
        mine = _still_means(session, cal, name)
        for seg, p_k in mine.items():
            a_body = np.linalg.solve(T_0[:3, :3], own(chain["imu0"], ref[seg]))
            a_k = own(block, p_k)
            # the poses' means agree to their noise (0.01 m/s^2 per sample, 200 samples)
            assert np.linalg.norm(T_k[:3, :3] @ a_body - a_k) < 0.01, (name, seg)


def test_one_imu_formats_need_imu(calibrated, tmp_path):
    _, _, folder = calibrated
    proc = run("export", folder / "set.cal.json", "--format", "json")
    assert proc.returncode == 2 and "--imu NAME (reference, imu1, imu2)" in proc.stderr
    proc = run("export", folder / "set.cal.json", "--format", "json", "--imu", "imu2")
    assert proc.returncode == 0, proc.stderr
    proc = run("export", folder / "set.cal.json", "--format", "json", "--imu", "imu9")
    assert proc.returncode == 2 and "--imu imu9" in proc.stderr


def test_apply_each_imu_in_its_frame_or_the_reference(calibrated, tmp_path):
    """In the reference's frame and time, each IMU's gyro is the reference's, up to their
    noise: the rotation and the offset put it there (in its own frame it is not)."""
    session, cal, folder = calibrated
    out = tmp_path / "ref.h5"
    proc = run("apply", folder / "set.cal.json", folder / "set.h5", "-o", out,
               "--reference-frame")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    own = tmp_path / "own.h5"
    assert run("apply", folder / "set.cal.json", folder / "set.h5", "-o", own).returncode == 0
    with h5py.File(out, "r") as f, h5py.File(own, "r") as g:
        assert f.attrs["frame"] == "reference" and list(f.attrs["imus"]) == [
            "reference", "imu1", "imu2"]  # fmt: skip
        t_r, w_r = f["calibrated/time"][()], f["calibrated/gyro"][()]
        for name in ("imu1", "imu2"):
            t, w = f[f"calibrated_imus/{name}/time"][()], f[f"calibrated_imus/{name}/gyro"][()]
            t_own, w_own = g[f"calibrated_imus/{name}/time"][()], g[
                f"calibrated_imus/{name}/gyro"][()]  # fmt: skip
            assert len(t) == len(session.imus[name].time)  # every sample, none resampled
            moving = np.linalg.norm(w, axis=1) > 0.3
            inside = moving & (t > t_r[0]) & (t < t_r[-1])

            def gap(times, values, rows=inside):
                ref = np.column_stack([np.interp(times, t_r, w_r[:, i]) for i in range(3)])
                return float(np.sqrt(np.mean((values[rows] - ref[rows]) ** 2)))

            noise = 0.005 * 2 * 2  # rad/s: each IMU's noise up to twice the reference's
            assert gap(t, w) < noise, name
            assert gap(t_own, w_own) > 2 * gap(t, w), name
    one = tmp_path / "imu1.csv"
    proc = run("apply", folder / "set.cal.json", folder / "set.h5", "-o", one, "--imu", "imu1")
    assert proc.returncode == 0, proc.stderr
    assert one.read_text().splitlines()[0] == "t,ax,ay,az,gx,gy,gz"
    proc = run("apply", folder / "set.cal.json", folder / "set.h5", "-o", tmp_path / "x.csv")
    assert proc.returncode == 2 and "a CSV holds one IMU" in proc.stderr


def test_apply_a_set_to_another_unit_warns(calibrated, tmp_path):
    """The set's own session: no warning; the same IMUs named as another unit: one warning
    per IMU named otherwise, the output written all the same."""
    session, _, folder = calibrated
    same = run("apply", folder / "set.cal.json", folder / "set.h5", "-o", tmp_path / "a.h5",
               "--json")  # fmt: skip
    assert same.returncode == 0 and json.loads(same.stdout)["warnings"] == []
    other = dataclasses.replace(session, sensor="FC-2 #0042")  # the reference's name
    write_session(tmp_path / "other.h5", other)
    proc = run("apply", folder / "set.cal.json", tmp_path / "other.h5", "-o",
               tmp_path / "b.h5", "--json")  # fmt: skip
    assert proc.returncode == 0 and (tmp_path / "b.h5").exists()
    (warning,) = json.loads(proc.stdout)["warnings"]
    assert "(reference)" in warning and "is from 'FC-2 #0042'" in warning


@pytest.mark.parametrize("offset", ["1e300", "NaN", '"soon"'])
def test_apply_refuses_a_time_offset_no_set_has(calibrated, tmp_path, offset):
    """Audit: an IMU's time_offset_s of 1e300 or NaN shifted every time apply
    --reference-frame wrote (1e300 or NaN), exit 0; now one line naming the key."""
    _, cal, folder = calibrated
    doc = json.loads((folder / "set.cal.json").read_text())
    doc["imus"]["imu1"]["time_offset_s"] = "@OFFSET@"
    path = tmp_path / "c.json"
    path.write_text(json.dumps(doc).replace('"@OFFSET@"', offset))
    out = tmp_path / "a.h5"
    proc = run("apply", path, folder / "set.h5", "-o", out, "--reference-frame")
    assert_one_line_error(proc, "imus.imu1.time_offset_s", "within +-3600")
    assert not out.exists()


def test_a_reference_named_by_the_recorder_is_found_by_export_and_apply(tmp_path):
    """The spec lets the recorder name the reference (``imus`` = ["IMU.0", ...], as imports of
    PX4, ArduPilot and ROS logs do): the calibration keeps that name, so ``export --imu`` and
    ``apply --imu`` take it, and ``reference`` too, and both give the same samples."""
    from dataclasses import replace

    session, _ = simulate_set(2, seed=4, units="m/s^2", created=CREATED)
    session = replace(session, reference_name="IMU.0")
    cal = calibrate_set(session, Config(), name="named.h5")
    assert cal.reference_name == "IMU.0"
    write_session(tmp_path / "named.h5", session)
    write_calibration(tmp_path / "named.cal.json", cal)
    for name in ("IMU.0", "reference"):
        proc = run("export", tmp_path / "named.cal.json", "--format", "json", "--imu", name)
        assert proc.returncode == 0, (name, proc.stderr)
        out = tmp_path / f"{name}.csv"
        proc = run("apply", tmp_path / "named.cal.json", tmp_path / "named.h5", "-o", out,
                   "--imu", name)  # fmt: skip
        assert proc.returncode == 0, (name, proc.stderr)
    a = np.genfromtxt(tmp_path / "IMU.0.csv", delimiter=",", names=True)
    b = np.genfromtxt(tmp_path / "reference.csv", delimiter=",", names=True)
    assert len(a) == len(session.time) and np.array_equal(a["az"], b["az"])


def test_report_shows_every_imu_and_its_place(calibrated):
    """``report`` of a set shows the other IMUs too: each one's rotation and time offset with
    their std, and its own sections (the JSON's ``imus``), not the reference alone."""
    import json

    _, cal, folder = calibrated
    proc = run("report", folder / "set.cal.json", "--json")
    assert proc.returncode == 0, proc.stderr
    imus = json.loads(proc.stdout)["imus"]
    assert list(imus) == ["imu1", "imu2"]
    for name, shown in imus.items():
        entry = cal.imus[name]
        assert shown["rotation_deg"] == pytest.approx(entry.rotation_deg)
        assert shown["time_offset_s"] == pytest.approx(entry.time_offset_s)
        assert set(shown["sensors"]) == {"accel", "gyro"}
        bias = shown["sensors"]["accel"]["bias"]
        assert bias == pytest.approx(list(entry.accel.bias))
    text = run("report", folder / "set.cal.json").stdout
    assert "imu1: rotated" in text and "imu2 gyro:" in text


def test_every_command_refuses_a_set_whose_imus_attribute_leaves_a_group_out(calibrated,
                                                                             tmp_path):
    """The spec ("Several IMUs"): "The root attribute `imus` lists every IMU's name, the
    reference's first".  A group of /imus it leaves out makes the file contradict itself:
    calibrate, report, noise, apply (of the set, and of one IMU, which reads /raw alone) and
    label all refuse it the same way (export reads calibrations, never a session), exit 2 and
    one line naming the group; the same file with the attribute whole is read by each (noise
    then judges its 2 s holds)."""
    import shutil

    from imucal_cli.formats.calibration import calibration_to_json
    from imucal_cli.formats.session import store_calibration
    from imucal_cli.model.calibration import Calibration

    from .cli_helpers import assert_one_line_error

    _, cal, folder = calibrated
    good, bad = tmp_path / "good.h5", tmp_path / "bad.h5"
    shutil.copy(folder / "set.h5", good)
    store_calibration(good, calibration_to_json(cal))
    shutil.copy(good, bad)
    with h5py.File(bad, "r+") as f:
        f.attrs["imus"] = np.array(["reference", "imu1"], dtype=h5py.string_dtype())
    single = tmp_path / "single.json"  # the reference's own: apply reads /raw alone
    write_calibration(single, Calibration(accel=cal.accel, gyro=cal.gyro, created=CREATED))
    commands = {
        "calibrate": ("calibrate", "{}", "--no-store", "-o", tmp_path / "c.json", "--force"),
        "report": ("report", "{}"),
        "noise": ("noise", "{}", "--json"),
        "apply set": ("apply", folder / "set.cal.json", "{}", "-o", tmp_path / "a.h5",
                      "--force"),
        "apply one": ("apply", single, "{}", "-o", tmp_path / "o.h5", "--force"),
        "label": ("label", "{}", "--faces", "--dry-run"),
    }  # fmt: skip
    for name, args in commands.items():
        proc = run(*(bad if a == "{}" else a for a in args))
        assert_one_line_error(proc, f"{bad}: /imus holds imu2 but the file lists only "
                              "reference, imu1 in its root attribute 'imus'")  # fmt: skip
        if name == "calibrate":  # (a set's calibration: seconds; the refusal is the point)
            continue
        proc = run(*(good if a == "{}" else a for a in args))
        if name == "noise":  # read, and judged on its samples: 2 s holds, no Allan deviation
            assert_one_line_error(proc, "too short for an Allan deviation")
        else:
            assert proc.returncode == 0, (name, proc.stderr)
