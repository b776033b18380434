"""``bench live``'s figures and verdicts (issue 24.1): one row per plan and mode.

A row pools the graded parameters of its seeds (:mod:`bench.live_grade`): the RMS of their
error over the Cramér-Rao bound, live and for the same seeds simulated to a file, and the
fraction of reported 95 % intervals that hold the truth.  Its verdict:

- **exit**: every capture complete and calibrated (exit 0), with the sensors the file gives;
- **error/bound**: live within :data:`TARGET` (10 %) of the file's; the ratio's 95 % interval
  from the seeds drawn again (bootstrap) says how far the seeds can tell.  A guided row's
  file is the mean of the held file's draws of the person's timing on each seed
  (:func:`bench.live_person.person_draws`), and its pass band is the wider of the target and
  the ratio's :data:`CONFIDENCE` interval when each capture is one of its seed's draws
  (:func:`person_interval`): widened only by that measured sampling error, never below the
  target, so a live path worse than the draws by more than both still fails;
- **coverage**: live not further from the file's than their sampling allows, and holding 95 %
  in its own (Wilson) interval.  Both are tests, two per row, so each is made at the
  family-wise level of the table (:func:`family_z`, Bonferroni over ``2 x rows``: z 3.28 for
  24 rows): 48 tests each at 95 % would fail a path that loses nothing 91 % of the time
  (1 - 0.95^48), at 1 - 0.05 / 48 at most one time in twenty.  A live coverage whose interval
  misses 95 % where the file of the same seeds misses alike, parameter by parameter
  (McNemar's paired test, one-sided at 5 %, on the intervals one side holds and the other
  misses; unattended, the very samples), its own interval below 95 %, while the file over
  all its seeds holds
  95 %, is those seeds' draw, not the path's: said in a note, not failed (free:12 seeds 0-2:
  82.5 % live and file, the file 93.2 % over seeds 0-59 and 94.9 % over 60-259).  The
  intervals of one
  seed's parameters are not independent (one seed's errors share its poses and noise: a seed
  that misses tends to miss several terms), so both take the plan's design effect
  (:func:`design_effect`, Kish: the variance of the pooled fraction between seeds over the
  binomial one, from the file's seeds): the number of intervals counts as ``n / deff``.

A failure is stated with what caused it where the figures can tell: a live result that the
file of the same seed shares (a calibration refused, a coverage the file misses over all its
seeds) is the solver's, not the capture's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from rich.console import Console
from rich.table import Table
from scipy.special import ndtri

from bench.live_grade import Graded

#: The accuracy target: live error/bound within this fraction of the file's.
TARGET = 0.10
#: The nominal coverage of the reported intervals.
NOMINAL = 0.95
#: The confidence of the person's sampling interval on a guided row's ratio
#: (:func:`person_interval`).
CONFIDENCE = 0.95


def pool(graded: list[dict], sections: list[set]) -> tuple[np.ndarray, np.ndarray]:
    """Squared error/bound ratios and interval hits of the ``sections`` of each seed."""
    z2, hits = [], []
    for g, keep in zip(graded, sections, strict=True):
        for name in sorted(keep):
            sec = g.get(name)
            if not isinstance(sec, Graded):
                continue
            if sec.z2 is not None:
                z2.append(sec.z2)
            hits.append(sec.hits)
    cat = lambda xs: np.concatenate(xs) if xs else np.zeros(0)  # noqa: E731
    return cat(z2), cat(hits).astype(bool)


def rms(z2: np.ndarray) -> float:
    return float(np.sqrt(np.mean(z2))) if len(z2) else float("nan")


def family_z(family: int, level: float = CONFIDENCE) -> float:
    """The normal quantile of a two-sided test at ``level`` family-wise over ``family`` tests
    (Bonferroni): 1.96 for one, 3.28 for 48."""
    return float(ndtri(1.0 - (1.0 - level) / (2 * max(int(family), 1))))


def wilson(hits: np.ndarray, z: float = 1.96, deff: float = 1.0) -> tuple[float, float]:
    """The (Wilson) interval of a fraction of ``hits`` at the normal quantile ``z`` (1.96:
    95 %), the hits counting as ``len(hits) / deff`` independent ones (``deff``:
    :func:`design_effect`)."""
    n = len(hits) / deff
    if n == 0:
        return float("nan"), float("nan")
    p = float(hits.mean())
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def design_effect(per_seed: list[np.ndarray]) -> float:
    """Kish's design effect of interval hits clustered by seed (``per_seed``: each seed's
    hits): the between-seed (cluster-robust) variance of the pooled fraction,
    ``k / (k - 1) sum_i (h_i - p m_i)^2 / (sum_i m_i)^2`` (seed ``i``: ``h_i`` of ``m_i``
    intervals held), over the binomial ``p (1 - p) / sum_i m_i``; 1 where it cannot be told
    (fewer than 2 seeds, every or no interval held) and never below 1."""
    m = np.array([len(h) for h in per_seed], float)
    h = np.array([np.sum(x) for x in per_seed], float)
    k, n = len(m), float(m.sum()) if len(m) else 0.0
    p = h.sum() / n if n else 0.0
    if k < 2 or p <= 0.0 or p >= 1.0:
        return 1.0
    between = k / (k - 1) * float(np.sum((h - p * m) ** 2)) / n**2
    return max(between / (p * (1 - p) / n), 1.0)


def sensors(g: dict) -> set:
    """The graded sections of one seed."""
    return {k for k, v in g.items() if isinstance(v, Graded)}


@dataclass
class Row:
    """The figures of one plan and mode (seeds: ``attempted``)."""

    plan: str
    mode: str
    attempted: int = 0
    complete: int = 0
    calibrated: int = 0
    saved: str = ""
    live: float = float("nan")
    file_same: float = float("nan")
    ratio: float = float("nan")
    ratio_ci: tuple[float, float] = (float("nan"), float("nan"))
    person_ci: tuple[float, float] = (float("nan"), float("nan"))
    band: tuple[float, float] = (1.0 - TARGET, 1.0 + TARGET)
    cover_live: float = float("nan")
    cover_ci: tuple[float, float] = (float("nan"), float("nan"))
    n_intervals: int = 0
    cover_file: float = float("nan")
    cover_file_ci: tuple[float, float] = (float("nan"), float("nan"))
    #: intervals the file's holds and live's misses, and the reverse (None: not the same
    #: parameters on both sides, so not paired)
    discordant: tuple[int, int] | None = None
    cover_tol: float = float("nan")
    file_all: float = float("nan")
    cover_all: float = float("nan")
    cover_all_ci: tuple[float, float] = (float("nan"), float("nan"))
    deff: float = 1.0
    z: float = 1.96
    file_n: int = 0
    wall: str = ""
    served: str = ""
    why: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    sections: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.why

    @property
    def blocked(self) -> bool:
        return bool(self.why) and self.why[0].startswith("blocked")


# --------------------------------------------------------------------------------------------
# One row
# --------------------------------------------------------------------------------------------


def _exits(row: Row, jobs: list, file_of: dict) -> None:
    """Captures complete, calibrations saved, the sensors the file gives; each failure in
    its own words, and the solver's where the file of the same seed fails the same way."""
    row.complete = sum(j.capture.exit_code == 0 for j in jobs)
    row.calibrated = sum(j.calibrate is not None and j.calibrate.exit_code == 0 for j in jobs)
    walls = [j.capture.wall_s for j in jobs]
    row.wall = f"{np.median(walls):.0f} ({max(walls):.0f})" if walls else ""
    left: dict[str, int] = {}
    for j in jobs:
        for sensor in (j.calibrate.left_out if j.calibrate else {}):
            left[sensor] = left.get(sensor, 0) + 1
    saved = {s for j in jobs if j.calibrate for s in j.calibrate.sections}
    row.saved = "+".join(s for s in ("accel", "gyro", "mag") if s in saved) or "-"
    if left:
        row.saved += "; left out: " + ", ".join(f"{s} {n}/{len(jobs)}" for s, n in left.items())
    equal = [j.served_equal for j in jobs if j.served_equal is not None]
    row.served = f"{100 * min(equal):.1f} %" if equal else "-"
    for j in jobs:  # each failure in its own words (the whole log: STEM.log beside it)
        said = j.what_went_wrong()
        if not said:
            continue
        same = "error" in file_of.get(j.seed, {}) and j.capture.exit_code == 0
        row.why.append(f"seed {j.seed}: {said}" + (" [solver: the file of this seed fails "
                       "too]" if same else ""))  # fmt: skip
    for j in jobs:
        f = file_of.get(j.seed, {})
        fewer = sorted(sensors(f) - sensors(j.graded)) if j.graded else []
        for name in fewer:
            why = (j.calibrate.left_out or {}).get(name, "") if j.calibrate else ""
            row.why.append(f"seed {j.seed}: {name} left out, the file calibrates it"
                           + (f" ({_short(why)})" if why else ""))  # fmt: skip
        for name, sec in j.graded.items():
            if isinstance(sec, str) and sec.startswith("not graded"):
                row.why.append(f"seed {j.seed} {name} {sec}")
    failed = {s: f["error"] for s, f in file_of.items() if "error" in f}
    if failed:
        row.notes.append(f"file reference: {len(failed)} of {len(file_of)} seeds not "
                         f"calibrated (e.g. {_short(next(iter(failed.values())))})")  # fmt: skip


def _short(text: str, n: int = 160) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 3] + "..."


def held_factor(file_of: dict, held_of: dict | None) -> float:
    """``sqrt(sum z^2 of the file / sum z^2 of the held reference)`` over the seeds both
    graded (their shared sections): what turns the held
    reference's error/bound into the file's as simulated (1 without a held reference).  Its
    own sampling error is that of the seeds' paired difference (40 seeds: 1.5-3 %)."""
    if held_of is None or held_of is file_of:
        return 1.0
    seeds = [s for s in file_of if s in held_of]
    keep = [sensors(file_of[s]) & sensors(held_of[s]) for s in seeds]
    z_file, _ = pool([file_of[s] for s in seeds], keep)
    z_held, _ = pool([held_of[s] for s in seeds], keep)
    return float(np.sqrt(z_file.sum() / z_held.sum())) if z_held.sum() > 0 else float("nan")


def _figures(row: Row, pairs: list, file_of: dict, rng, held_of: dict | None = None,
             draws_of: dict | None = None) -> list[set]:  # fmt: skip
    """Error/bound and coverage, live and file, pooled over the seeds both graded.  With
    ``held_of`` (the pairs' reference: the file held as a guided capture holds) the ratio is
    to the held file of the same seeds: the same plan simulated to a file with the holds the
    capture took (its ``--hold``), sharing the capture's samples.  The hold is the user's
    choice, not the live path's doing: :func:`held_factor`, what the device's longer holds
    would change (the estimator's error/bound is not the same at every hold length where its
    bound is not tight, hwangbo-iron's labelled fit: 0.82 at 2 s, 0.68 at 4 s over 40 seeds),
    is said in a note, not counted in the ratio.  With ``draws_of`` (``{seed: [graded
    draws]}``, :func:`bench.live_person.person_draws`) the error/bound reference is the
    draws' mean on each seed and the ratio's pass band takes their spread
    (:func:`person_interval`); the coverage stays the pairs'."""
    both = [sensors(j.graded) & sensors(f) for j, f in pairs]
    z_live, h_live = pool([j.graded for j, _ in pairs], both)
    z_file, h_file = pool([f for _, f in pairs], both)
    drawn = _drawn(pairs, both, draws_of)
    row.live, row.file_same = rms(z_live), rms(z_file)
    if drawn is not None:
        row.file_same = _mean_rms(drawn)
    row.ratio = row.live / row.file_same
    per = None
    if drawn is not None:  # each seed's live sum, and its draws' mean for as many parameters
        lives = [pool([j.graded], [b])[0] for (j, _), b in zip(pairs, both, strict=True)]
        per = [(z.sum(), d[:, 0].mean() * z.size / d[:, 1].mean())
               for z, d in zip(lives, drawn, strict=True)]  # fmt: skip
    row.ratio_ci = _bootstrap(pairs, both, rng, per=per)
    if drawn is not None:
        row.person_ci = person_interval(drawn, rng)
        row.band = (min(1.0 - TARGET, row.person_ci[0]), max(1.0 + TARGET, row.person_ci[1]))
        counts = sorted({len(d) for d in drawn})
        times = str(counts[0]) if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
        row.notes.append(f"error/bound against the file held as the guided capture holds, the "
                         f"person's timing drawn {times} times per seed (their mean); that "
                         f"timing alone spreads the ratio over {row.person_ci[0]:.3f}-"
                         f"{row.person_ci[1]:.3f} ({100 * CONFIDENCE:.0f} %): pass band "
                         f"{row.band[0]:.3f}-{row.band[1]:.3f}")  # fmt: skip
    elif draws_of is not None:
        row.notes.append("the person's draws do not cover every seed and sensor: the ratio "
                         "is to the file held at the mean timing")  # fmt: skip
    k = held_factor(file_of, held_of)
    if k != 1.0:
        row.notes.append(f"paired with the file held as the guided capture holds; the file as "
                         f"simulated (the device's holds) is {k:.3f} times that over "
                         f"{len(file_of)} seeds (the hold's part, not the path's)")  # fmt: skip
    every = [f for f in file_of.values() if sensors(f)]
    z_all, h_all = pool(every, [sensors(f) for f in every])
    row.deff = design_effect([pool([f], [sensors(f)])[1] for f in every])
    row.cover_live, row.cover_file = float(h_live.mean()), float(h_file.mean())
    row.cover_ci, row.n_intervals = wilson(h_live, row.z, row.deff), len(h_live)
    row.cover_file_ci = wilson(h_file, row.z, row.deff)
    row.discordant = _discordant(pairs, both)
    p = (h_live.sum() + h_file.sum()) / (len(h_live) + len(h_file))
    row.cover_tol = row.z * float(np.sqrt(p * (1 - p) * row.deff
                                         * (1 / len(h_live) + 1 / len(h_file))))  # fmt: skip
    row.file_all, row.cover_all, row.file_n = rms(z_all), float(h_all.mean()), len(every)
    row.cover_all_ci = wilson(h_all, row.z, row.deff)
    _per_sensor(row, pairs, both, every, draws_of if drawn is not None else None)
    return both


def _discordant(pairs: list, both: list[set]) -> tuple[int, int] | None:
    """Over the parameters live and file both graded under the same names: how many of the
    file's intervals hold the truth where live's miss, and the reverse (None where a section's
    parameters differ: another solver on one side)."""
    worse = better = 0
    for (j, f), keep in zip(pairs, both, strict=True):
        for name in keep:
            a, b = j.graded[name], f[name]
            if list(a.names) != list(b.names):
                return None
            worse += int(np.sum(b.hits & ~a.hits))
            better += int(np.sum(a.hits & ~b.hits))
    return worse, better


def _per_sensor(row: Row, pairs: list, both: list[set], every: list,
                draws_of: dict | None) -> None:  # fmt: skip
    """Each sensor's figures in ``row.sections`` (the file's error/bound the draws' mean
    where ``draws_of`` is given)."""
    for name in sorted(set().union(*both)):
        keep = [{name} if name in b else set() for b in both]
        zl, hl = pool([j.graded for j, _ in pairs], keep)
        zf, hf = pool([f for _, f in pairs], keep)
        mine = [(p, k) for p, k in zip(pairs, keep, strict=True) if k]
        drawn = _drawn([p for p, _ in mine], [k for _, k in mine], draws_of)
        _, ha = pool(every, [{name} for _ in every])
        solvers = [(j.graded[name].solver, f[name].solver) for (j, f), b in
                   zip(pairs, both, strict=True) if name in b]  # fmt: skip
        live_s = "/".join(sorted({s for s, _ in solvers}))
        file_s = "/".join(sorted({s for _, s in solvers}))
        row.sections[name] = (live_s, file_s, rms(zl),
                              rms(zf) if drawn is None else _mean_rms(drawn),
                              float(hl.mean()), float(hf.mean()),
                              float(ha.mean()) if len(ha) else float("nan"))  # fmt: skip
        if live_s != file_s:
            row.notes.append(f"{name}: solver {live_s} where the file's is {file_s}")


def _drawn(pairs: list, both: list[set], draws_of: dict | None) -> list[np.ndarray] | None:
    """Per pair, ``(sum of z^2, parameters)`` of each of its seed's draws that graded every
    section the pair shares (an array (draws, 2)); None without ``draws_of`` or where a seed
    has fewer than 3 such draws."""
    if draws_of is None:
        return None
    out = []
    for (j, _), keep in zip(pairs, both, strict=True):
        sums = []
        for d in draws_of.get(j.seed, []):
            z, _ = pool([d], [keep]) if keep <= sensors(d) else (np.zeros(0), None)
            if len(z):
                sums.append((float(z.sum()), len(z)))
        if len(sums) < 3:
            return None
        out.append(np.array(sums))
    return out


def _mean_rms(drawn: list[np.ndarray]) -> float:
    """The error/bound of the draws' mean on each seed, pooled over the seeds."""
    return float(np.sqrt(sum(d[:, 0].mean() for d in drawn) / sum(d[:, 1].mean() for d in drawn)))


def person_interval(drawn: list[np.ndarray], rng, n: int = 4000,
                    level: float = CONFIDENCE) -> tuple[float, float]:  # fmt: skip
    """The ``level`` interval of the live/file ratio when the live path loses nothing: each
    seed's capture one of its seed's draws of the person's timing (``drawn``: per seed, each
    draw's ``(sum of z^2, parameters)``), its reference the mean of the others (leave one
    out: the reference's own sampling error is in it too); ``n`` draws of one pick per
    seed."""
    num = den = ref_z = ref_n = 0.0
    for d in drawn:
        pick = rng.integers(0, len(d), n)
        num, den = num + d[pick, 0], den + d[pick, 1]
        others = len(d) - 1
        ref_z = ref_z + (d[:, 0].sum() - d[pick, 0]) / others
        ref_n = ref_n + (d[:, 1].sum() - d[pick, 1]) / others
    ratio = np.sqrt((num / den) / (ref_z / ref_n))
    q = (1.0 - level) / 2
    return float(np.quantile(ratio, q)), float(np.quantile(ratio, 1.0 - q))


def _verdict(row: Row) -> None:
    """Error/bound within the target, coverage as the file's and holding 95 %."""
    lo, hi = row.ratio_ci
    seeds = f"{row.attempted} seed(s)"
    if not np.isfinite(row.ratio):
        row.why.append("no bound for any graded parameter")
    elif not row.band[0] <= row.ratio <= row.band[1]:
        tell = ("" if not np.isfinite(lo) else f"; 95 % over the seeds {lo:.2f}-{hi:.2f}"
                + (": the seeds cannot tell it from 1" if lo <= 1 <= hi else ""))  # fmt: skip
        wider = row.band != (1.0 - TARGET, 1.0 + TARGET)
        band = (f"; the person's timing alone {row.person_ci[0]:.2f}-{row.person_ci[1]:.2f}: "
                f"band {row.band[0]:.2f}-{row.band[1]:.2f}" if wider else "")  # fmt: skip
        row.why.append(f"error/bound {row.live:.3f} vs the file's {row.file_same:.3f} "
                       f"({100 * (row.ratio - 1):+.0f} %, target within {100 * TARGET:.0f} %"
                       f"{band}{tell}, {seeds})")  # fmt: skip
    if abs(row.cover_live - row.cover_file) > row.cover_tol:
        row.why.append(f"coverage {100 * row.cover_live:.1f} % vs the file's "
                       f"{100 * row.cover_file:.1f} % on the same seeds (more than "
                       f"{100 * row.cover_tol:.1f} points apart)")  # fmt: skip
    clo, chi = row.cover_ci
    if np.isfinite(clo) and not clo <= NOMINAL <= chi:
        _short_coverage(row)


def _holds(ci: tuple[float, float]) -> bool:
    return bool(np.isfinite(ci[0]) and ci[0] <= NOMINAL <= ci[1])


#: One-sided normal quantile of the paired test that lets a short live coverage be the seeds'
#: (:func:`_shared`): 5 %, not family-wise, since it excuses a failure rather than makes one.
SHARED_Z = float(ndtri(0.95))


def _shared(row: Row) -> bool:
    """Live's intervals miss no more than the file's of the same seeds, paired parameter by
    parameter (McNemar's test on the discordant ones, one-sided at 5 %: :data:`SHARED_Z`),
    and the file's own interval lies below 95 %."""
    if row.discordant is None or not np.isfinite(row.cover_file_ci[1]):
        return False
    worse, better = row.discordant
    return bool(row.cover_file_ci[1] < NOMINAL
                and worse - better <= SHARED_Z * np.sqrt(worse + better))  # fmt: skip


def _short_coverage(row: Row) -> None:
    """A live coverage whose interval misses 95 %: the solver's where the file's over all its
    seeds misses too; the seeds' draw (a note) where the file of the same seeds misses alike,
    paired parameter by parameter (:func:`_shared`), and the file over all its seeds holds
    95 %; else the path's."""
    clo, chi = row.cover_ci
    alo, ahi = row.cover_all_ci
    said = (f"coverage {100 * row.cover_live:.1f} % ({100 * clo:.0f}-{100 * chi:.0f} %, "
            f"{row.n_intervals} intervals, design effect {row.deff:.1f}, "
            f"z {row.z:.2f})")  # fmt: skip
    over_all = (f"the file's over {row.file_n} seeds is {100 * row.cover_all:.1f} % "
                f"({100 * alo:.0f}-{100 * ahi:.0f} %)")  # fmt: skip
    if np.isfinite(alo) and not _holds(row.cover_all_ci):
        row.why.append(f"{said} does not hold {100 * NOMINAL:.0f} % [solver: {over_all}]")
    elif _shared(row):
        row.notes.append(f"{said} misses {100 * NOMINAL:.0f} % as the file of the same seeds "
                         f"does ({100 * row.cover_file:.1f} %), and {over_all}: these seeds' "
                         "draw, not the path's")  # fmt: skip
    else:
        row.why.append(f"{said} does not hold {100 * NOMINAL:.0f} %")


def make_row(name: str, mode: str, jobs: list, file_of: dict, rng,
             same_of: dict | None = None, draws_of: dict | None = None,
             family: int = 1) -> Row:  # fmt: skip
    """The figures and verdict of plan ``name`` in ``mode``: its jobs (:class:`bench.live.Job`)
    and the file reference of every seed (``{seed: graded sections}``).  ``same_of``: the
    reference each seed's live figures are paired with where not ``file_of`` (guided
    captures: the file held as the capture holds, :func:`bench.live.held_as_guided`, over
    the same seeds as ``file_of``; :func:`held_factor` in a note); the all-seeds figures
    stay ``file_of``'s.  ``draws_of``: ``{seed: [graded draws]}``, the held file with the
    person's timing drawn (:func:`bench.live_person.person_draws`): the error/bound
    reference (their mean) and the ratio's pass band (:func:`person_interval`)."""
    row = Row(name, mode, attempted=len(jobs), z=family_z(family))
    same_of = file_of if same_of is None else same_of
    _exits(row, jobs, same_of)  # whose failures a live one shares: the reference it is paired with
    pairs = [(j, same_of.get(j.seed, {})) for j in jobs if j.graded]
    pairs = [(j, f) for j, f in pairs if sensors(j.graded) & sensors(f)]
    if not pairs:
        row.why.append("nothing to grade")
        return row
    _figures(row, pairs, file_of, rng, None if same_of is file_of else same_of, draws_of)
    _verdict(row)
    return row


def _bootstrap(pairs, both, rng, draws: int = 1000, per: list | None = None
               ) -> tuple[float, float]:  # fmt: skip
    """95 % interval of the live/file ratio when the seeds are drawn again (with
    replacement); NaN with fewer than 3 seeds.  ``per``: each seed's ``(live, file)`` sums of
    z^2, where not the pairs'."""
    if per is None:
        per = []
        for (j, f), keep in zip(pairs, both, strict=True):
            zl, _ = pool([j.graded], [keep])
            zf, _ = pool([f], [keep])
            per.append((zl.sum(), zf.sum()))
    if len(per) < 3:
        return float("nan"), float("nan")
    a = np.array(per)
    idx = rng.integers(0, len(a), (draws, len(a)))
    sums = a[idx].sum(axis=1)
    ok = sums[:, 1] > 0
    if not ok.any():  # no parameter graded in both (no sensor saved from both): no ratio
        return float("nan"), float("nan")
    ratio = np.sqrt(sums[ok, 0] / sums[ok, 1])
    return float(np.quantile(ratio, 0.025)), float(np.quantile(ratio, 0.975))


# --------------------------------------------------------------------------------------------
# Printing
# --------------------------------------------------------------------------------------------


def _fmt(x: float, spec: str = ".3f") -> str:
    return "-" if not np.isfinite(x) else format(x, spec)


def _pct(ci: tuple[float, float]) -> str:
    return "-" if not np.isfinite(ci[0]) else f"{100 * ci[0]:.0f}-{100 * ci[1]:.0f}"


def print_rows(console: Console, rows: list[Row], title: str) -> None:
    """The table, the per-sensor table and every failure's reasons."""
    t = Table(title=title)
    for col in ("plan", "mode", "seeds: tried/complete/calibrated", "sensors saved",
                "err/bound live", "file", "live/file (95 %)", "coverage live (95 %)",
                "file, same seeds", "file, all seeds: err/bound, coverage (95 %)",
                "served = simulated", "capture wall s, median (max)", ""):  # fmt: skip
        t.add_column(col, justify="right")
    for r in rows:
        ci = "" if not np.isfinite(r.ratio_ci[0]) else f" ({_fmt(r.ratio_ci[0], '.2f')}-" \
             f"{_fmt(r.ratio_ci[1], '.2f')})"  # fmt: skip
        t.add_row(
            r.plan, r.mode, f"{r.attempted}/{r.complete}/{r.calibrated}", r.saved,
            _fmt(r.live), _fmt(r.file_same), _fmt(r.ratio) + ci,
            f"{_fmt(100 * r.cover_live, '.1f')} ({_pct(r.cover_ci)}, n={r.n_intervals}, "
            f"deff {r.deff:.1f})",
            f"{_fmt(100 * r.cover_file, '.1f')} (± {_fmt(100 * r.cover_tol, '.1f')})",
            f"{_fmt(r.file_all)}, {_fmt(100 * r.cover_all, '.1f')} ({_pct(r.cover_all_ci)}; "
            f"{r.file_n} seeds)", r.served, r.wall,
            "[yellow]BLOCKED[/]" if r.blocked else "[green]PASS[/]" if r.ok else "[red]FAIL[/]",
        )  # fmt: skip
    console.print(t)
    s = Table(title="per sensor: solver live / file; error/bound live / file; coverage live / "
                    "file (same seeds) / file (all seeds)")  # fmt: skip
    for col in ("plan", "mode", "sensor", "solver", "file's", "err/bound live", "file",
                "coverage live", "file", "file, all"):  # fmt: skip
        s.add_column(col, justify="right")
    for r in rows:
        for name, (sl, sf, zl, zf, hl, hf, ha) in r.sections.items():
            s.add_row(r.plan, r.mode, name, sl, sf if sf != sl else "same", _fmt(zl), _fmt(zf),
                      _fmt(100 * hl, ".1f"), _fmt(100 * hf, ".1f"), _fmt(100 * ha, ".1f"))
    console.print(s)
    for r in rows:
        if r.why or r.notes:
            console.print(f"  {r.plan} {r.mode}: " + "; ".join(r.why + r.notes), highlight=False)
