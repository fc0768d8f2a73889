"""`rtcal uncertainty`: does the reported uncertainty match the errors? (GUM Supplement 1)

The simulated bench is the virtual experiment: the procedure is run N times, each trial with
fresh random draws (every instrument's noise, the stage's repeatability, a polygon
certificate's error) and, unless ``vary_systematics`` is off, with the quantities the budget
treats as unknown systematic errors drawn from the distributions the procedure states (the
CMM's scales and squareness, the table's error motions within their bounds). Each trial's
every estimate is compared with the bench's truth; per target the RMS error over the trials
is set beside the RMS of the 1σ the estimates reported.

A trial is a whole run — engine, SQLite store, dataset, solvers — in its own directory,
so what is checked is what a user runs. Trials run on a process pool by default, or on an
existing Dask cluster (``scheduler`` address), with a progress bar.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import yaml

from rtcal.procedure.models import Procedure


@dataclass(frozen=True)
class TrialSpec:
    """One trial: the procedure file, the trial's bench (YAML text) and its seed."""

    index: int
    procedure_path: str
    scenario_yaml: str
    seed: int
    workdir: str


class ScriptedNormals:
    """A stand-in for ``numpy.random.Generator`` in ``draw_systematics`` that hands out given
    standard normal deviates in order (``normal``, ``standard_normal``; ``uniform`` through the
    normal's distribution function), and counts what was asked of it."""

    def __init__(self, z: np.ndarray | None = None):
        self._z = np.zeros(0) if z is None else np.asarray(z, float).ravel()
        self.used = 0

    def _take(self, size) -> np.ndarray:
        count = int(np.prod(size)) if size is not None else 1
        if self._z.size:
            if self.used + count > self._z.size:
                raise RuntimeError("the scripted draws ran out: the method drew more than it did when counted")
            out = self._z[self.used:self.used + count]
        else:
            out = np.zeros(count)
        self.used += count
        return out.reshape(size) if size is not None else out[0]

    def standard_normal(self, size=None):
        return self._take(size)

    def normal(self, loc=0.0, scale=1.0, size=None):
        return loc + scale * self._take(size)

    def uniform(self, low=0.0, high=1.0, size=None):
        from scipy.special import ndtr

        return low + (high - low) * ndtr(self._take(size))


def balanced_normals(pairs: int, dimension: int, rng: np.random.Generator) -> np.ndarray:
    """(2·pairs, dimension) standard normal deviates drawn in antithetic pairs (z, −z), the ``pairs``
    base draws whitened so that their second moments are exactly the identity (needs pairs ≥ dimension):
    every linear function of the draws then has exactly its expected mean (0) and variance over the
    trials, and the systematic errors' share of the squared errors carries no sampling noise."""
    z = rng.standard_normal((pairs, dimension))
    if dimension:
        if pairs < dimension:
            raise ValueError(f"balanced draws need at least {dimension} pairs of trials ({2 * dimension} trials): the "
                             f"method draws {dimension} numbers per trial")
        chol = np.linalg.cholesky(z.T @ z / pairs)
        z = np.linalg.solve(chol, z.T).T  # z·L⁻ᵀ: second moments exactly I
    out = np.empty((2 * pairs, dimension))
    out[0::2], out[1::2] = z, -z
    return out


def plan_trials(procedure_path: Path, proc: Procedure, scenario, trials: int, seed: int, workdir: Path,
                vary_systematics: bool = True, balanced: bool = False) -> list[TrialSpec]:
    """N trial specifications; the systematic draws come from one generator seeded by ``seed``
    (``balanced``: in moment-matched antithetic pairs, :func:`balanced_normals`; N even)."""
    from rtcal.methods import METHODS

    method = METHODS[proc.method]
    rng = np.random.default_rng([seed, 0x5EED])
    scripted: np.ndarray | None = None
    if vary_systematics and balanced:
        counter = ScriptedNormals()
        method.draw_systematics(proc, scenario, counter)  # type: ignore[arg-type]
        if trials % 2:
            raise ValueError("balanced draws come in antithetic pairs: give an even number of trials")
        scripted = balanced_normals(trials // 2, counter.used, rng)
    specs = []
    for k in range(trials):
        if not vary_systematics:
            bench = scenario
        elif scripted is not None:
            bench = method.draw_systematics(proc, scenario, ScriptedNormals(scripted[k]))  # type: ignore[arg-type]
        else:
            bench = method.draw_systematics(proc, scenario, rng)
        data = bench.model_dump(mode="json")
        data["seed"] = int(seed) * 100003 + k
        specs.append(TrialSpec(k, str(procedure_path), yaml.safe_dump(data, sort_keys=False), data["seed"], str(workdir)))
    return specs


def run_trial(spec: TrialSpec, single_thread: bool = True) -> dict[str, Any]:
    """Run one trial; return per estimator the error against truth and the reported 1σ per target
    (``per_estimator``), the recommended estimator and the target labels; or why it ``failed``."""
    from threadpoolctl import threadpool_limits

    from rtcal.run.runner import AnalysisFailed, run_procedure

    trial_dir = Path(tempfile.mkdtemp(prefix=f"trial{spec.index:05d}-", dir=spec.workdir))
    try:
        scenario_path = trial_dir / "bench.yaml"
        scenario_path.write_text(spec.scenario_yaml, encoding="utf-8")
        with threadpool_limits(1 if single_thread else None):
            try:
                outcome = run_procedure(spec.procedure_path, scenario_path, spec.seed, trial_dir / "run",
                                        show_progress=False, outputs=False)
            except AnalysisFailed as exc:
                return {"index": spec.index, "failed": str(exc)}
        r = outcome.results
        if r.truth is None:
            return {"index": spec.index, "failed": "the trial's results carry no truth"}
        truth = np.asarray(r.truth.cumulative_deviation_arcsec, float)
        per_estimator: dict[str, dict[str, Any]] = {}
        for name, est in r.estimates.items():
            cum = np.array([np.nan if v is None else v for v in est.cumulative_deviation_arcsec], float)
            u = np.array([np.nan if v is None else v for v in est.cumulative_uncertainty_arcsec], float)
            if len(cum) != len(truth):  # an estimate on other targets than the truth's (none today)
                continue
            test = getattr(est, "residual_test", None)
            per_estimator[name] = {"error": (cum - truth).tolist(), "u": u.tolist(), "status": r.solver_status[name].status,
                                   "residual_test_passed": None if test is None else bool(test.passed),
                                   "residual_test": None if test is None else test.model_dump()}
        return {"index": spec.index, "recommended": r.recommended, "per_estimator": per_estimator,
                "labels": r.target_labels()}
    finally:
        shutil.rmtree(trial_dir, ignore_errors=True)


def run_trials(specs: list[TrialSpec], workers: int | None = None,
               scheduler: str | None = None) -> Iterator[dict[str, Any]]:
    """Trials as they complete: on a local process pool, in this process (workers = 1), or on Dask."""
    if scheduler:
        from distributed import Client, as_completed as dask_completed

        with Client(scheduler, timeout="10s") as client:
            futures = client.map(run_trial, specs, pure=False)
            for fut in dask_completed(futures):
                yield fut.result()
        return
    workers = workers or os.cpu_count() or 1
    if workers == 1:
        for spec in specs:
            yield run_trial(spec, single_thread=False)
        return
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for fut in as_completed([pool.submit(run_trial, s) for s in specs]):
            yield fut.result()


def summarize(trials: list[dict[str, Any]], target_labels: list[str]) -> dict[str, Any]:
    """Per estimator and target: RMS error, RMS reported 1σ, their ratio, and the mean error (bias)."""
    ok = [t for t in trials if "failed" not in t]
    names = sorted({n for t in ok for n in t["per_estimator"]})
    out: dict[str, Any] = {"trials": len(trials), "failed_trials": len(trials) - len(ok), "targets": target_labels,
                           "estimators": {}}
    recs = [t["recommended"] for t in ok]
    out["recommended"] = max(set(recs), key=recs.count) if recs else None
    for name in names:
        rows = [t["per_estimator"][name] for t in ok if name in t["per_estimator"]]
        err = np.array([r["error"] for r in rows], float)
        u = np.array([r["u"] for r in rows], float)
        rms_err = np.sqrt(np.nanmean(err**2, axis=0))
        rms_u = np.sqrt(np.nanmean(u**2, axis=0))
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = rms_u / rms_err
        inner = slice(1, None)  # the first target is the reference: 0 ± 0 by definition
        with np.errstate(invalid="ignore"):
            covered = np.abs(err[:, inner]) <= 2.0 * u[:, inner]  # U (k = 2) covers the error
        counted = np.isfinite(err[:, inner]) & np.isfinite(u[:, inner])
        tested = [r["residual_test_passed"] for r in rows if r.get("residual_test_passed") is not None]
        out["estimators"][name] = {
            "trials": len(rows),
            # the share of trials whose residual test failed (on a bench as the budget models it: its false-alarm rate)
            "residual_test_failed": round(1.0 - sum(tested) / len(tested), 4) if tested else None,
            "not_converged": sum(r["status"] != "converged" for r in rows),
            "rms_error_arcsec": _r(rms_err), "rms_reported_sigma_arcsec": _r(rms_u), "ratio": _r(ratio, 3),
            # its 1σ from the number of trials (an RMS of N normal errors is known to ±1/√(2N))
            "ratio_sigma": _r(ratio / np.sqrt(2 * len(rows)), 3),
            "mean_error_arcsec": _r(np.nanmean(err, axis=0)),
            "overall": {"rms_error_arcsec": round(float(np.sqrt(np.nanmean(err[:, inner] ** 2))), 4),
                        "rms_reported_sigma_arcsec": round(float(np.sqrt(np.nanmean(u[:, inner] ** 2))), 4),
                        "ratio_min": round(float(np.nanmin(ratio[inner])), 3) if np.any(np.isfinite(ratio[inner])) else None,
                        "ratio_max": round(float(np.nanmax(ratio[inner])), 3) if np.any(np.isfinite(ratio[inner])) else None,
                        # the share of (trial, target) pairs whose error the reported U (k = 2) covers
                        "coverage_k2": round(float(np.sum(covered & counted) / max(int(np.sum(counted)), 1)), 4)},
        }
    out["recommended_estimate"] = recommended_summary(ok)
    return out


def recommended_summary(ok: list[dict[str, Any]]) -> dict[str, Any] | None:
    """What a certificate quotes, trial by trial: each trial's own recommended estimate (it may change between trials)
    — its coverage (k = 2), RMS reported 1σ over RMS error, bias, and how often its residual test failed, when the
    certificate says its U is not a coverage interval; ``coverage_k2_quoted``: the coverage over the trials whose test
    passed, the ones whose U the certificate quotes without that warning (None: none passed)."""
    rows = [(t["per_estimator"][t["recommended"]]) for t in ok if t.get("recommended") in t.get("per_estimator", {})]
    if not rows:
        return None
    err = np.array([r["error"] for r in rows], float)[:, 1:]
    u = np.array([r["u"] for r in rows], float)[:, 1:]
    counted = np.isfinite(err) & np.isfinite(u)
    with np.errstate(invalid="ignore"):
        covered = (np.abs(err) <= 2.0 * u) & counted
    failed = np.array([r.get("residual_test_passed") is False for r in rows])
    quoted = ~failed
    names = [t["recommended"] for t in ok if t.get("recommended") in t.get("per_estimator", {})]
    mean = np.nanmean(err, axis=0)
    return {
        "trials": len(rows), "estimators": {n: names.count(n) for n in sorted(set(names))},
        "coverage_k2": round(float(np.sum(covered) / max(int(np.sum(counted)), 1)), 4),
        "ratio": round(float(np.sqrt(np.nanmean(u**2)) / np.sqrt(np.nanmean(err**2))), 3) if np.nanmean(err**2) > 0 else None,
        "mean_error_arcsec": round(float(np.nanmean(mean)), 4),
        "largest_mean_error_arcsec": round(float(mean[np.nanargmax(np.abs(mean))]), 4),
        "residual_test_failed": round(float(np.mean(failed)), 4),
        "coverage_k2_quoted": round(float(np.sum(covered[quoted]) / max(int(np.sum(counted[quoted])), 1)), 4)
        if np.any(quoted) else None,
    }


def _r(a: np.ndarray, digits: int = 4) -> list:
    return [None if not np.isfinite(v) else round(float(v), digits) for v in np.asarray(a, float)]


def plot_summary(summary: dict[str, Any], title: str, path: Path) -> Path:
    """Per estimator: RMS error against the RMS reported 1σ per target, and their ratio."""
    from rtcal.deliverables.figures import legend_below, plt

    names = list(summary["estimators"])
    fig, axes = plt.subplots(len(names), 2, figsize=(11, 3.6 * len(names) + 0.8), squeeze=False,
                             gridspec_kw={"width_ratios": [3, 2]}, layout="constrained")
    x = np.arange(len(summary["targets"]))
    labels = summary["targets"]
    for row, name in zip(axes, names):
        e = summary["estimators"][name]
        err = np.array([np.nan if v is None else v for v in e["rms_error_arcsec"]])
        u = np.array([np.nan if v is None else v for v in e["rms_reported_sigma_arcsec"]])
        ratio = np.array([np.nan if v is None else v for v in e["ratio"]])
        row[0].bar(x - 0.2, err, 0.4, label="RMS error against truth")
        row[0].bar(x + 0.2, u, 0.4, label="RMS of the reported 1σ")
        row[0].set_ylabel("arcsec")
        row[0].set_title(f"{name}{' (recommended)' if name == summary['recommended'] else ''}: "
                         f"{e['trials']} trials", fontsize=10)
        row[1].axhspan(0.8, 1.25, color="C2", alpha=0.15, label="0.8–1.25")
        # the ratio's own 1σ from a finite number of trials: about ratio/√(2N)
        row[1].errorbar(x[1:], ratio[1:], yerr=ratio[1:] / np.sqrt(2 * e["trials"]), fmt="o-", color="C3", capsize=3,
                        label=f"reported 1σ / RMS error (bars: ±1σ of {e['trials']} trials)")
        row[1].axhline(1.0, color="0.5", lw=0.8)
        row[1].set_ylim(0, max(2.0, float(np.nanmax(ratio[1:])) * 1.1 if np.any(np.isfinite(ratio[1:])) else 2.0))
        row[1].set_ylabel("reported 1σ / RMS error")
        for ax, room in zip(row, (40, 24)):  # labels like "-115↑" stand upright, at most `room` to a panel
            every = -(-len(x) // room)
            ax.set_xticks(x[::every], labels[::every], fontsize=7, rotation=90 if len(x) > 4 else 0)
            ax.set_xlim(-0.6, len(x) - 0.4)  # both panels on the same targets, none on the frame
            ax.grid(alpha=0.3)
    axes[-1][0].set_xlabel("target: commanded angle / °, ↑ positive or ↓ negative approach\n"
                           "(the first is the reference: its deviation is 0 by definition)")
    axes[-1][1].set_xlabel("target")
    fig.suptitle(title, fontsize=11)
    legend_below(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def table_lines(targets: list, estimator: dict) -> list[str]:
    """An estimator's Monte Carlo result as a row per target (the first, the reference, left out):
    RMS error, RMS reported 1σ, their ratio and its own 1σ; narrow enough for any number of targets."""
    def cell(values: list, k: int, spec: str) -> str:
        v = values[k] if k < len(values) else None
        return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)

    lines = [f"  {'target':>10}  {'RMS error / ″':>14}  {'reported 1σ / ″':>16}  {'ratio':>6}  {'± 1σ':>6}"]
    for k in range(1, len(targets)):
        lines.append(f"  {str(targets[k]):>10}  {cell(estimator['rms_error_arcsec'], k, '.3f'):>14}  "
                     f"{cell(estimator['rms_reported_sigma_arcsec'], k, '.3f'):>16}  {cell(estimator['ratio'], k, '.2f'):>6}  "
                     f"{cell(estimator.get('ratio_sigma', []), k, '.2f'):>6}")
    return lines
