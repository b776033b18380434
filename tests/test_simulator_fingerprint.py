"""Every plan's simulated session and truth, bit for bit: a seed is a session.

``imucal simulate --plan P --seed 1`` (:func:`imucal_cli.simulate.play.simulate_plan`, and
:func:`imucal_cli.simulate.magnetometer.simulate_mag` for ``--mag``) must give the same
datasets, segments and truth after a change of the simulator's code: a refactor that moves a
draw or reassociates a product changes these digests.  The digests were taken with the numpy
and scipy versions in :data:`VERSIONS`; under other versions (whose random streams or rotation
arithmetic may differ in the last bit) the test skips.  Regenerate them, only after checking
that a change of the sessions is meant, with ``python tests/test_simulator_fingerprint.py``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest
import scipy

from imucal_cli.formats.calibration import calibration_to_json

CREATED = "2000-01-01T00:00:00Z"
VERSIONS = {"numpy": "2.4", "scipy": "1.17"}

CASES: dict[str, dict] = {
    "six": {"plan": "six"},
    "qureshi18": {"plan": "qureshi18"},
    "random:5": {"plan": "random:5"},
    "gyro-axes": {"plan": "gyro-axes"},
    "hwangbo-iron": {"plan": "hwangbo-iron"},
    "hk-gyro:3": {"plan": "hk-gyro", "mountings": 3},
    "hk-redundant": {"plan": "hk-redundant"},
    "hk-redundant labelled": {"plan": "hk-redundant", "labelled": True},
    "qureshi-axes": {"plan": "qureshi-axes"},
    "qureshi-axes:3 m/s^2": {"plan": "qureshi-axes:3", "units": "m/s^2"},
    "free:6": {"plan": "free:6"},
    "still:1": {"plan": "still:1"},
    "warmup:2": {"plan": "warmup:2"},
    "qureshi18 ramp": {"plan": "qureshi18", "ramp": "20:40"},
    "free:4 clock ramp": {"plan": "free:4", "clock_ppm": 50.0, "ramp": "25:35:linear"},
    "six m/s^2 jitter 5": {"plan": "six", "units": "m/s^2", "jitter_deg": 5.0},
    "six mag": {"plan": "six", "mag": True},
}

DIGESTS = {
    'six': '979cae56064c7d3128d477ee66cdffae5ffa2906d4ebdb85f7dda00ffd0bcd27',
    'qureshi18': '120d9a04ff39f04968ba47e10604a252acc695867e8bf50bb667e4fa7abe237c',
    'random:5': 'b2c570976f5157ca8fb92b66b1f995ed7c7acc09e74570e7df6961c448ed5022',
    'gyro-axes': 'bb55d9c78ea47b3d7fb282a922f14e71113b480bb019aeadf94bd0e1f17f86e7',
    'hwangbo-iron': '1bba6f9ea78da25b9da1da94da62fab4b5f21b71e309db87ff4b8dc0255077b7',
    'hk-gyro:3': '0d7f795e736364db4848d21ecefcee7dccf37ed0f8ae1cde4f035a297b64e8c6',
    'hk-redundant': 'd5f1c11545c534d4fb7ea09de2a005837ce566bcd27d40ac44d6964572447f7a',
    'hk-redundant labelled': '54a04dd354384f3fee91b9ab40d57f9124aab1338f530c8b6d548195325d9743',
    'qureshi-axes': 'd9d89b1d4c9640ed2778872c90e4ba01ff67a87668d7ad960ea94cd813aece79',
    'qureshi-axes:3 m/s^2': '3f38cb154a10eb7c32b57b0981c67b18feefb106eda4d8835a34cb078441bded',
    'free:6': '64dadea35b56c8a9a9be4b5cf2a8c257a5962622c955a7ca1ff8b98220791b00',
    'still:1': '6f3312cac85f2a99eeb30e6766dc7bd9538f40a316668f7c0ed8113dc258ad3e',
    'warmup:2': '1406575626a495168f048e0125d39638b23a7cd96fb40ad546bba7989b312cf8',
    'qureshi18 ramp': 'f1efdf66520d43e90a747e93c496eeee3bc750180c03ed64e0b12c3599a6e28a',
    'free:4 clock ramp': '2745c9e354f7a78e7813a109eec6d44f71737c77ef9de3acff61bdf74ed5dcbc',
    'six m/s^2 jitter 5': 'f84c6ab34172d0cc191d66d3ad8a9c3c327331f2e60daa530f2a8189c9ac575d',
    'six mag': 'df69c50320c5d60e830e7fe0425faf773dd0dbfeb8bb9a60f371f4d701581ac1',
}


def simulate_case(case: dict):
    """The session and truth ``imucal simulate`` makes of a case, with seed 1."""
    from imucal_cli.simulate.clock import check_ppm
    from imucal_cli.simulate.play import simulate_plan
    from imucal_cli.simulate.temperature import parse_ramp

    options = dict(case)
    plan = options.pop("plan")
    if options.pop("mag", False):
        from imucal_cli.simulate.magnetometer import simulate_mag

        return simulate_mag(plan, 1, created=CREATED, hold_s=2.0, **options)
    if "ramp" in options:
        options["temperature"] = parse_ramp(options.pop("ramp"))
    if "clock_ppm" in options:
        options["clock_scale"] = check_ppm(options.pop("clock_ppm"))
    return simulate_plan(plan, seed=1, created=CREATED, **options)


def _feed(h, value) -> None:
    if isinstance(value, np.ndarray):
        h.update(f"{value.dtype.str}{value.shape}".encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, list | tuple):
        h.update(f"[{len(value)}".encode())
        for v in value:
            _feed(h, v)
    elif dataclasses.is_dataclass(value):
        for f in dataclasses.fields(value):
            h.update(f.name.encode())
            _feed(h, getattr(value, f.name))
    else:
        h.update(repr(value).encode())


def fingerprint(session, truth) -> str:
    """SHA-256 of every field of the session (datasets, segments, metadata) and of the truth
    JSON."""
    h = hashlib.sha256()
    _feed(h, session)
    h.update(calibration_to_json(truth).encode())
    return h.hexdigest()


def _versions() -> dict:
    return {m.__name__: ".".join(m.__version__.split(".")[:2]) for m in (np, scipy)}


@pytest.mark.parametrize("name", list(CASES))
def test_seed_gives_the_recorded_session(name):
    if _versions() != VERSIONS:
        pytest.skip(f"digests taken with {VERSIONS}, running {_versions()}")
    session, truth = simulate_case(CASES[name])
    assert fingerprint(session, truth) == DIGESTS[name]


if __name__ == "__main__":
    print(json.dumps(_versions()))
    for name, case in CASES.items():
        print(f"    {name!r}: {fingerprint(*simulate_case(case))!r},")
