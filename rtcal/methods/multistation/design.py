"""`rtcal plan --optimize`: choose CMM points that lower the network estimator's predicted 1σ.

The network's information about its global unknowns (axis, radius, station angles, dead path,
CMM scales and squareness) is a sum over points: each point's lengths to every station, with
the point's own coordinates eliminated (its Schur complement, its reported position a weighted
observation). So a plan's predicted covariance is (Σ I_i)⁻¹ over its points, and exchanging one
point for another is a g×g update. A greedy exchange over a grid of candidates in the CMM volume
minimises the mean predicted variance of the cumulative deviation (A-optimality on what the
certificate reports), keeping the number of points; candidates closer to the axis than the
plan's closest point are excluded (the table and the tracer are there).
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np
import yaml

from rtcal.methods.planner import keep_bench
from rtcal.outputs import write_output
from rtcal.methods.multistation.procedure import LaserTracerMultistation
from rtcal.solvers.network import _Layout, _model, solve_network
from rtcal.units import ARCSEC_PER_RAD
from rtcal.procedure.yamlfile import load_yaml, read_text

if TYPE_CHECKING:
    from rtcal.api import Scenario


def point_information(x_globals: np.ndarray, lay_template: _Layout, points_mm: np.ndarray,
                      w_length: Callable[[np.ndarray], np.ndarray], w_point: float, m: int) -> np.ndarray:
    """(K, g, g): each point's Schur-reduced information about the globals (lengths to all m stations)."""
    K = len(points_mm)
    lay = _Layout(m, lay_template.k, K, True, True)
    x = np.concatenate([x_globals, points_mm.ravel()])
    pi, sj = np.repeat(np.arange(K), m), np.tile(np.arange(m), K)
    seg = np.zeros(K * m, int)
    obs = np.zeros(K * m)
    f_len, Jg, Jp, f_pts, Jg_pts, P, A, Minv = _model(x, lay, pi, sj, seg, obs, points_mm, np.zeros(6))
    L = np.linalg.norm(A[pi] - P[sj], axis=1)
    w = w_length(L)
    g = lay.g
    Jg3, Jp3, w3 = Jg.reshape(K, m, g), Jp.reshape(K, m, 3), w.reshape(K, m)
    Ngg = np.einsum("kma,km,kmb->kab", Jg3, w3, Jg3)
    Ngp = np.einsum("kma,km,kmb->kab", Jg3, w3, Jp3)
    Npp = np.einsum("kma,km,kmb->kab", Jp3, w3, Jp3)
    Jgp = Jg_pts.reshape(K, 3, g)
    Ngg += np.einsum("ika,ikb->iab", Jgp, Jgp) * w_point
    Ngp += np.einsum("ika,kb->iab", Jgp, Minv) * w_point
    Npp += np.einsum("ka,kb->ab", Minv, Minv)[None] * w_point
    info: np.ndarray = Ngg - np.einsum("kab,kbc,kdc->kad", Ngp, np.linalg.inv(Npp), Ngp)
    return info


def _criterion(info: np.ndarray, G: np.ndarray) -> float:
    """Mean predicted variance of the cumulative deviation (arcsec²), ∞ if the plan is singular."""
    try:
        C = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.inf
    v = np.einsum("ia,ab,ib->i", G, C, G)[1:]
    return float(np.mean(v)) if np.all(v > 0) else np.inf


def exchange(current: np.ndarray, candidates: np.ndarray, G: np.ndarray, passes: int = 20) -> tuple[np.ndarray, float, float]:
    """Greedy exchange: swap a chosen point for a candidate while that lowers the criterion.
    ``current`` (n, g, g) and ``candidates`` (K, g, g) informations; returns chosen candidate indices
    (−1: an original point kept, in order) and the criterion before and after."""
    chosen = list(range(-len(current), 0))  # negative: original points
    infos = {-(i + 1): current[i] for i in range(len(current))}
    total = current.sum(axis=0)
    before = best = _criterion(total, G)
    for _ in range(passes):
        improved = False
        for slot, idx in enumerate(chosen):
            base = total - infos[idx]
            used = set(chosen)
            trial = [(_criterion(base + candidates[c], G), c) for c in range(len(candidates)) if c not in used]
            if not trial:
                continue
            value, c = min(trial)
            if value < best * (1 - 1e-6):
                best, total, chosen[slot] = value, base + candidates[c], c
                infos[c] = candidates[c]
                improved = True
        if not improved:
            break
    return np.array(chosen), before, best


def optimize_points(procedure_path: Path, proc: LaserTracerMultistation, scenario: Scenario, out_path: Path,
                    simulate: Callable[[Path, Path, Path], None], grid: int = 7) -> str:
    """Write ``out_path``: the procedure with an optimised point list; returns a summary line.
    ``simulate(procedure, bench, run_dir)`` runs the procedure on the noise-free bench (the runner's)."""
    from rtcal.methods.multistation.dataset import multistation_data
    from rtcal.methods.multistation.noise import noise_model
    from rtcal.store.runstore import RunStore

    noise = noise_model(proc, estimate=False)
    tmp = Path(tempfile.mkdtemp(prefix="design-"))
    try:
        bench = tmp / "bench.yaml"
        bench.write_text(yaml.safe_dump(scenario.without_noise().model_dump(mode="json"), sort_keys=False), encoding="utf-8")
        simulate(procedure_path, bench, tmp / "run")
        store = RunStore.open(tmp / "run")
        data = multistation_data(store, proc.stations.angles_deg(), len(proc.points_array()))
        store.close()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    est = solve_network(data, np.array(proc.solver.first_station_guess_mm), np.array(proc.solver.axis_point_mm), noise)
    m = len(est.angles_rad)
    lay = _Layout(m, 1, 0, True, True)
    xg = np.zeros(lay.g)
    xg[lay.c] = est.axis_point_mm
    xg[lay.a] = est.axis_direction[:2]
    xg[lay.r] = est.radius_mm
    xg[lay.phi] = est.angles_rad
    xg[lay.d] = est.dead_paths_mm[:1]
    a_mm, b = max(noise.length_noise_um, 1e-4) * 1e-3, noise.length_noise_ppm * 1e-6
    w_length = lambda L: 1.0 / (a_mm + b * L) ** 2  # noqa: E731
    w_point = 1.0 / (max(noise.point_noise_um, 1e-3) * 1e-3) ** 2
    G = np.zeros((m, lay.g))
    G[:, lay.phi] = np.eye(m) * ARCSEC_PER_RAD
    G[:, lay.phi.start] -= ARCSEC_PER_RAD
    points = proc.points_array()
    lo = np.maximum(np.array(proc.instruments.cmm.volume_min_mm), np.array(scenario.cmm.volume_min_mm))
    hi = np.minimum(np.array(proc.instruments.cmm.volume_max_mm), np.array(scenario.cmm.volume_max_mm))
    axes = [np.linspace(lo[k], hi[k], grid) for k in range(3)]
    cand = np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T
    keep_out = float(np.min(np.linalg.norm(points[:, :2] - est.axis_point_mm[:2], axis=1)))
    z_min = float(np.min(points[:, 2]))
    cand = cand[(np.linalg.norm(cand[:, :2] - est.axis_point_mm[:2], axis=1) >= keep_out) & (cand[:, 2] >= z_min)]
    current = point_information(xg, lay, points, w_length, w_point, m)
    candidates = point_information(xg, lay, cand, w_length, w_point, m)
    chosen, before, after = exchange(current, candidates, G)
    new_points = np.array([points[-c - 1] if c < 0 else cand[c] for c in chosen])
    order = np.lexsort((new_points[:, 0], new_points[:, 1], new_points[:, 2]))  # layer by layer, row by row
    new_points = new_points[order]
    data_yaml, _ = load_yaml(read_text(procedure_path), str(procedure_path))
    data_yaml["points"] = {"kind": "list", "points_mm": [[round(float(v), 3) for v in p] for p in new_points]}
    copy = keep_bench(procedure_path, data_yaml, out_path)
    data_yaml["name"] = f"{data_yaml.get('name') or procedure_path.stem} — points optimised by rtcal plan"
    write_output(out_path, "# Written by `rtcal plan --optimize`: CMM points chosen to lower the network estimator's "
                 "predicted 1σ.\n" + yaml.safe_dump(data_yaml, sort_keys=False, allow_unicode=True, default_flow_style=None))
    kept = int(np.sum(chosen < 0))
    written = f"{out_path} (its bench copied to {copy})" if copy is not None else str(out_path)
    return (f"optimised plan written to {written}: {len(points) - kept} of {len(points)} points moved (candidates: "
            f"{len(cand)} on a {grid}³ grid in the CMM volume, at least {keep_out:.0f} mm from the axis); predicted RMS 1σ "
            f"from the tracer and CMM noise "
            f"of the network's cumulative deviation {np.sqrt(before):.3f}″ → {np.sqrt(after):.3f}″")
