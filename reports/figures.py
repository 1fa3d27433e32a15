"""Figures of a study (matplotlib, written as PNG): performance profiles, convergence bands of every
solver, before/after side views (naive droop against the optimized strands, coloured by stiffening,
like the supplement's Fig. 4), stiffening along the strand, sag per strand, stability per strand and
time against strand size.

Stiffening is the bend modulus over the strand's Young's modulus at each interior vertex (1 =
as specified), read from ``Result.physical`` so that every mode (element, strand) is comparable.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402

from sagfree.frontend.table import SOLVERS  # noqa: E402

from .benchmarking import PROFILE_SHIFTS, common_count, comparable_cases, costs, performance_profile  # noqa: E402
from .study import Study  # noqa: E402

DPI = 130
#: Sags below this (including exactly 0: Newton found nothing to correct) are drawn at it.
SAG_FLOOR = 1e-14


def bend_multiplier(strand, result) -> np.ndarray:
    """Bend modulus / E per interior vertex, from the Result's physical parameters (Problem.physical,
    whatever mode and bodies the Problem had)."""
    return np.asarray(result.physical["bend_modulus"]) / strand.youngs_modulus


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _band(ax, x: np.ndarray, rows: list, label: str, log: bool = False):
    """The median of ``rows`` (one per strand) against x as a line, the 10-90% band shaded."""
    low, middle, high = np.percentile(np.array(rows), [10, 50, 90], axis=0)
    line, = (ax.semilogy if log else ax.plot)(x, middle, label=f"{label}, {len(rows)} strands")
    if len(rows) > 1:
        ax.fill_between(x, low, high, color=line.get_color(), alpha=0.2, linewidth=0)


def _plain_ticks(*axes) -> None:
    """Plain numbers on log axes (2, 5, 10, not 2 x 10^0), no minor labels."""
    for axis in axes:
        if not isinstance(axis.get_major_locator(), matplotlib.ticker.FixedLocator):
            axis.set_major_locator(matplotlib.ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        axis.set_minor_formatter(matplotlib.ticker.NullFormatter())


def _scene_axes(count: int, width: float = 4.2, height: float = 3.0):
    columns = min(count, 3)
    rows = -(-count // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(width * columns, height * rows), squeeze=False)
    for ax in axes.ravel()[count:]:
        ax.set_visible(False)
    return fig, axes.ravel()


#: |c|_inf at or below this (including exactly 0) is drawn at it
HISTORY_FLOOR = 1e-16


def convergence(study: Study, path: Path) -> Path:
    """|c|_inf after each primal step over every strand of each scene: the median and the 10-90%
    band per solver and mode (a strand that stopped keeps its last value)."""
    scenes = list(study.scenes)
    fig, axes = _scene_axes(len(scenes))
    for ax, scene in zip(axes, scenes):
        for case in (c for c in study.cases if c.scene == scene and c.results and c.solver != "naive"):
            histories = [np.maximum(np.asarray(r.history, dtype=float), HISTORY_FLOOR) for r in case.results
                         if r.history and np.all(np.isfinite(r.history))]
            if not histories:
                continue
            steps = max(len(h) for h in histories)
            _band(ax, np.arange(steps), [np.r_[h, np.full(steps - len(h), h[-1])] for h in histories], case.label,
                  log=True)
        ax.axhline(1e-8, color="gray", linestyle=":", linewidth=0.8)
        ax.set(title=scene, xlabel="primal step (own kind per solver)", ylabel="|c|_inf (unit-free)")
        ax.legend(fontsize=6)
    return _save(fig, path)


#: strands drawn per scene in the before/after figure
DROOP_STRANDS = 6


def droop(study: Study, path: Path, solver: str = "asc") -> Path:
    """Before and after, side view (x-z) of the first strands of each scene that has naive and
    ``solver`` cases: the static equilibrium the naive parameters relax into (left) and the one of
    ``solver``'s parameters (right, coloured by the bend multiplier), over the groomed shape (grey)."""
    from sagfree.formulation.problem import Problem
    from sagfree.formulation.simulation import equilibrium

    scenes = _droop_scenes(study, solver)
    fig, axes = plt.subplots(len(scenes), 2, figsize=(9.0, 3.6 * len(scenes)), squeeze=False, layout="constrained")
    drawn, options = [], study.settings.get("scene_options", {})
    for row, scene in enumerate(scenes):
        mode = study.settings["modes"][0]
        for column, name in enumerate(("naive", solver)):
            ax, case = axes[row, column], study.case(scene, name, mode)
            segments, colours = [], []
            for k, strand in enumerate(study.scenes[scene][: min(DROOP_STRANDS, len(case.results))]):
                result = case.results[k]
                if not np.all(np.isfinite(result.p)):
                    continue
                ax.plot(strand.points[:, 0], strand.points[:, 2], color="0.8", linewidth=3.0)
                problem = Problem(strand, stiffness=mode, **options.get(scene, {}))
                rest = equilibrium(problem, result.p).positions[:, [0, 2]]
                segments.extend(np.stack([rest[:-1], rest[1:]], axis=1))
                s = bend_multiplier(strand, result)
                colours.extend(np.r_[s[0], np.maximum(s[:-1], s[1:]), s[-1]])
            lines = LineCollection(segments, cmap="viridis", linewidths=1.2)
            lines.set_array(np.maximum(np.array(colours), 1.0))
            ax.add_collection(lines)
            drawn.append(lines)
            ax.autoscale()
            ax.set_aspect("equal", adjustable="datalim")
            ax.set(title=f"{scene}: {name}, static equilibrium", xlabel="x (m)", ylabel="z (m)")
    values = np.concatenate([np.asarray(lines.get_array()) for lines in drawn]) if drawn else np.ones(1)
    norm = matplotlib.colors.LogNorm(1.0, max(2.0, float(np.nanmax(values))))
    for lines in drawn:
        lines.set_norm(norm)
    if drawn:
        fig.colorbar(drawn[-1], ax=list(axes.ravel()), label="bend modulus / E", shrink=0.8)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _droop_scenes(study: Study, solver: str = "asc") -> list[str]:
    """The (first 3) scenes where ``droop`` has both naive and ``solver`` in the first mode."""
    mode = study.settings["modes"][0]
    return [s for s in study.scenes if study.case(s, "naive", mode) and study.case(s, solver, mode)][:3]


def stability(study: Study, path: Path) -> Path:
    """The smallest mass-normalized eigenvalue (s^-2) of every strand per case (symmetric log scale),
    marked by the push test: held (green), fell (red cross), not pushed (grey)."""
    cases = [c for c in study.cases if c.results and c.solver != "naive"]
    fig, ax = plt.subplots(figsize=(max(5.0, 0.6 * len(cases) + 2), 3.6))
    rng = np.random.default_rng(0)
    for k, case in enumerate(cases):
        values = np.array([r.min_eigenvalue for r in case.results])
        x = k + rng.uniform(-0.25, 0.25, values.size)
        pushed = [j < len(case.checks) and case.checks[j].push == case.checks[j].push for j in range(values.size)]
        held = [p and case.checks[j].holds for j, p in enumerate(pushed)]
        for mask, style in ((np.array(held), dict(color="tab:green", marker="o", s=8)),
                            (np.array(pushed) & ~np.array(held), dict(color="tab:red", marker="x", s=14)),
                            (~np.array(pushed), dict(color="0.6", marker="o", s=6))):
            if mask.any():
                ax.scatter(x[mask], values[mask], **style)
    ax.set_yscale("symlog", linthresh=1.0)
    ax.axhline(0.0, color="gray", linestyle=":", linewidth=0.8)
    ax.set_xticks(np.arange(len(cases)), [f"{c.scene}\n{c.label}" for c in cases], rotation=60, ha="right",
                  fontsize=6)
    ax.set(ylabel="smallest eigenvalue (s^-2)", title="stability per strand (green: holds after a push)")
    return _save(fig, path)


#: arclength samples of the stiffening profiles
PROFILE_SAMPLES = 60


def stiffening_along_arclength(strand, result) -> np.ndarray:
    """The bend multiplier at PROFILE_SAMPLES points of arclength / L in [0, 1], linear between the
    interior vertices (held constant towards the root and the tip)."""
    arc = np.r_[0.0, np.cumsum(strand.edge_lengths)] / strand.length
    return np.interp(np.linspace(0.0, 1.0, PROFILE_SAMPLES), arc[1:-1], bend_multiplier(strand, result))


def stiffening_profile(study: Study, path: Path) -> Path:
    """Bend multiplier along arclength over every converged strand of each scene: the median and the
    10-90% band per solver and mode (the supplement's Fig. 4 as a study figure)."""
    scenes = list(study.scenes)
    fig, axes = _scene_axes(len(scenes))
    grid = np.linspace(0.0, 1.0, PROFILE_SAMPLES)
    for ax, scene in zip(axes, scenes):
        strands = study.scenes[scene]
        for case in study.cases:
            if case.scene != scene or not SOLVERS[case.solver].uses_stiffness:
                continue  # naive and the predecessor keep p0's stiffness
            profiles = [stiffening_along_arclength(strands[k], r) for k, r in enumerate(case.results)
                        if r.status == "converged"]
            if profiles:
                _band(ax, grid, profiles, case.label)
        ax.axhline(1.0, color="gray", linestyle=":", linewidth=0.8)
        ax.set(title=scene, xlabel="arc length / L (root at 0)", ylabel="bend modulus / E", yscale="log")
        _plain_ticks(ax.yaxis)
        ax.legend(fontsize=6)
    return _save(fig, path)


def sag_comparison(study: Study, path: Path) -> Path:
    """Every simulated strand's sag over L (the larger of simulation and static solve), one column of
    dots per case; green: the solver converged on that strand. Log scale, zero drawn at FLOOR."""
    cases = [c for c in study.cases if c.checks]
    fig, ax = plt.subplots(figsize=(max(5.0, 0.6 * len(cases) + 2), 3.4))
    rng = np.random.default_rng(0)
    for k, case in enumerate(cases):
        sag = np.array([max(ch.relative_sag, ch.static_sag if np.isfinite(ch.static_sag) else 0.0)
                        for ch in case.checks])
        ok = np.array([r.status == "converged" for r in case.results[: len(sag)]])
        x = k + rng.uniform(-0.25, 0.25, sag.size)
        y = np.maximum(np.nan_to_num(sag, nan=1.0), SAG_FLOOR)
        ax.scatter(x[ok], y[ok], s=6, color="tab:green")
        ax.scatter(x[~ok], y[~ok], s=6, color="tab:red")
    ax.set_yscale("log")
    ax.axhline(1e-6, color="gray", linestyle=":", linewidth=0.8)
    ax.set_xticks(np.arange(len(cases)), [f"{c.scene}\n{c.label}" for c in cases], rotation=60, ha="right",
                  fontsize=6)
    ax.set(ylabel="sag / L", title="sag per strand (green: converged)")
    return _save(fig, path)


def time_against_size(study: Study, path: Path) -> Path:
    """Time per strand against its vertex count, per solver and mode (log-log)."""
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    series: dict[str, list[tuple[int, float]]] = {}
    for case in study.cases:
        strands = study.scenes[case.scene]
        series.setdefault(case.label, []).extend(
            (strands[k].n_vertices, r.time) for k, r in enumerate(case.results))
    for label, points in series.items():
        sizes = np.array(sorted({n for n, _ in points}))
        means = [np.mean([t for n, t in points if n == size]) for size in sizes]
        ax.loglog(sizes, 1e3 * np.array(means), marker="o", markersize=3, label=label)
    ax.set(xlabel="vertices per strand", ylabel="ms per strand (mean)", title="time against strand size")
    sizes = sorted({n for points in series.values() for n, _ in points})
    ax.xaxis.set_major_locator(matplotlib.ticker.FixedLocator(sizes))
    _plain_ticks(ax.xaxis, ax.yaxis)
    ax.legend(fontsize=6)
    return _save(fig, path)


def performance_profiles(study: Study, path: Path) -> Path:
    """Dolan-More profiles of time and major iterations per stiffness mode, over the strands of every
    scene that all optimizing solvers ran (benchmarking module)."""
    modes = list(dict.fromkeys(c.mode for c in study.cases))
    fig, axes = plt.subplots(len(modes), 2, figsize=(9.0, 3.2 * len(modes)), squeeze=False)
    for row, mode in enumerate(modes):
        for column, kind in enumerate(("time", "iterations")):
            table: dict[str, list] = {}
            for scene in study.scenes:
                cases = comparable_cases(study, scene, mode)
                count = common_count(cases)
                if len(cases) < 2 or count == 0:
                    continue
                for case in cases:
                    table.setdefault(case.solver, []).extend(costs(case, count, kind))
            ax = axes[row, column]
            if len({len(v) for v in table.values()}) != 1 or len(table) < 2:
                ax.set_visible(False)
                continue
            taus, rho = performance_profile({k: np.array(v) for k, v in table.items()}, PROFILE_SHIFTS[kind])
            for solver, values in rho.items():
                ax.step(taus, values, where="post", label=solver)
            problems = len(next(iter(table.values())))
            ax.set(xscale="log", ylim=(0, 1.02), xlabel=f"tau: {kind} over the best solver's on the strand",
                   ylabel="share of strands within tau", title=f"{mode} stiffness: {kind}, {problems} strands")
            ax.legend(fontsize=7, loc="lower right")
    return _save(fig, path)


def experiments_figure(frames, slerps, modes, path: Path) -> Path:
    """The supplement's experiments (reports.experiments runs): displacement over time of IV.A and
    IV.B, bend multiplier along the strand of V (S Figs. 2-4 as curves)."""
    from sagfree.scenes import flipped, horizontal

    lengths = {"horizontal": horizontal().length, "flipped": flipped().length}
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 3.6))
    styles = [dict(linestyle="-", linewidth=3.0, alpha=0.5), dict(linestyle="--", linewidth=2.0),
              dict(linestyle="-.", linewidth=1.5), dict(linestyle=":", linewidth=1.5)]
    for ax, runs, title in ((axes[0], frames, "IV.A: 2d-average vs 4d, E 1e10 Pa"),
                            (axes[1], slerps, "IV.B: 2d-slerp vs 4d, flipped frames")):
        for run, style in zip(runs, styles):
            label = f"{run.curvature}, {run.scene}" + (f", E {run.youngs_modulus:.0e} Pa" if runs is slerps else "")
            ax.plot(run.simulation.times, run.simulation.displacement / lengths[run.scene], label=label, **style)
        ax.set(xlabel="time (s)", ylabel="largest displacement / L", title=title)
        ax.legend(fontsize=6)
    for run in modes:
        bend = np.asarray(run.result.physical["bend_modulus"])
        multiplier = bend * run.bend_max / bend.max()  # bend_max is max(bend / E)
        axes[2].plot(np.linspace(0.0, 1.0, bend.size + 2)[1:-1], multiplier, marker=".", markersize=3,
                     label=f"{run.mode}: max {run.bend_max:.3g}, root response {run.root_response:.2g} L")
    axes[2].set(yscale="log", xlabel="interior vertex along the strand (root at 0)", ylabel="bend modulus / E",
                title="V: naive, per strand, per element, E 1e9 Pa")
    _plain_ticks(axes[2].yaxis)
    axes[2].legend(fontsize=6)
    return _save(fig, path)


FIGURES = {
    "profiles": (performance_profiles, "Performance profiles (Dolan-More): for each solver, the share of "
                 "strands it solves (`converged`) within a factor tau of the best solver's time (left, s, "
                 "compilation excluded) and major iterations (right: asc and penalty-gn Gauss-Newton steps, "
                 "ipopt iterations, osqp SQP steps; ratios of count + 1), over the strands every solver "
                 "ran. Higher is better; the value at tau = 1 is the share where the solver is the best."),
    "convergence": (convergence, "Convergence: |c|_inf (unit-free) after each primal step (asc: "
                    "Gauss-Newton steps; ipopt: iterations; osqp: SQP steps; penalty-gn: Gauss-Newton), the "
                    "median (line) and 10-90% band over the strands of each scene per solver; a strand that "
                    "stopped keeps its last value, zero is drawn at 1e-16. Dotted: the 1e-8 tolerance."),
    "droop": (droop, "Before and after: the first strands of each scene seen from the side (x-z, m), "
              "their static equilibrium with the naive parameters (left) and with our solver's (right), "
              "over the groomed shape (thick grey), coloured by the bend modulus over Young's modulus "
              "(1: as specified; log scale spanning the data). The naive strands droop; the optimized "
              "ones stay on their groom."),
    "stiffening": (stiffening_profile, "Stiffening along the strand: bend modulus over the specified "
                   "Young's modulus (1: as specified) against arc length over the strand length, over every "
                   "strand each solver converged on: the median (line) and the 10-90% band, per solver and "
                   "stiffness mode."),
    "sag": (sag_comparison, "Sag over strand length of every simulated strand (the larger of simulation and "
            "static solve), per case; red: strands the solver did not converge on; values below 1e-14 "
            "(or 0) drawn at 1e-14."),
    "stability": (stability, "Stability: the smallest mass-normalized eigenvalue of the free-DOF Hessian "
                  "at the groomed shape (omega^2 of the slowest mode, s^-2; symmetric log scale, linear "
                  "within +-1) of every strand per case; green: pushed along that mode and held, red cross: "
                  "pushed and fell, grey: not pushed."),
    "time": (time_against_size, "Mean time per strand (ms) against strand size (vertices), log-log."),
}


def draw_all(study: Study, directory: Path, sizes: Study | None = None) -> dict[str, Path]:
    """Every figure of FIGURES that the study has data for, as PNGs in ``directory``; the time figure
    only from ``sizes`` (a study of the same kind of strands at several sizes: the scenes of an
    ordinary study are unrelated, and a line through them would read as a sweep)."""
    directory.mkdir(parents=True, exist_ok=True)
    drawn = {}
    for name, (function, _) in FIGURES.items():
        if (name == "sag" and not any(c.checks for c in study.cases)) or (name == "time" and sizes is None):
            continue
        if name == "droop" and not _droop_scenes(study):
            continue
        if name == "profiles" and not any(len(comparable_cases(study, c.scene, c.mode)) > 1 for c in study.cases):
            continue
        drawn[name] = function(sizes if name == "time" else study, directory / f"{name}.png")
    return drawn
