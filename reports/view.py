"""An interactive 3D page of a groom (``sagfree view``; DESIGN section 10).

``write_view`` writes ONE self-contained HTML file (plotly.js inlined: the page needs no network)
that shows three states of every strand:

- groomed: the input shape q* (grey);
- naive: the static equilibrium q* relaxes into with the specified parameters p0
  (formulation.simulation.equilibrium at ``problem.p0``, all stiffness multipliers 1; orange);
- optimized: the static equilibrium of the strand's optimized parameters p, coloured by the bend
  stiffness multiplier per vertex on a log scale, with a colour bar. The multiplier is the bend
  modulus over Young's modulus (``Problem.physical``), which is the ``bend_stiffness`` block in
  ``stiffness="element"`` mode, the one strand multiplier in ``"strand"`` mode and 1 in ``"fixed"``
  mode (the colour bar's title says which). It lives on the interior vertices; the root vertex takes
  vertex 1's and the tip vertex n-2's, the values of the elements next to them.

The bodies the strands rest on (``problem_options["bodies"]``: Sphere, Capsule, Mesh) are drawn as
surfaces. Legend entries show and hide each state; a strand is picked by typing its index (or by
clicking one of its vertices, or with ``#strand=K`` in the address): it is drawn thick in its
optimized state (its groomed shape when it has none) and the bar above the plot shows its index,
status, largest multiplier and the naive and optimized static sags. Hovering a vertex shows its
strand and vertex index. A strand without usable parameters (missing, failed, not of its Problem's
size) is still drawn groomed and naive, and is marked: drawn red in its groomed shape, in a legend
entry of its own.

Size: one plotly trace per state, strands separated by gaps (not one trace per strand), built in
the browser from integer coordinates in units of RESOLUTION (0.1 um): the groomed state as each
strand's root and then vertex-to-vertex steps, the naive and optimized states as differences from
the groomed one (mostly 0 for an optimized strand that holds its shape). The page of the default
groom is plotly.js (~4.8 MB) and 0.25 MB of strands; 1.9K strands x 100 vertices add ~8 MB.
"""
from __future__ import annotations

import html
import traceback
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sagfree.formulation.bodies import Capsule, Mesh, Sphere, parse_body
from sagfree.formulation.problem import Problem
from sagfree.formulation.simulation import equilibrium
from sagfree.frontend.batch import map_strands
from sagfree.frontend.options import check_problem_options
from sagfree.scenes.file_io import write_bytes

from .view_page import page

#: metres per stored coordinate unit: every coordinate on the page is rounded to this
RESOLUTION = 1e-7
#: colour bar titles by stiffness mode (what the colour means there)
COLOUR_TITLES = {
    "element": "bend stiffness multiplier<br>per vertex (bend modulus / E)",
    "strand": "strand stiffness multiplier<br>(stiffness='strand': one per strand)",
    "fixed": "bend stiffness multiplier<br>(stiffness='fixed': always 1)",
}


@dataclass
class StrandStates:
    """What the page draws of one strand besides its groomed shape.

    naive, optimized: static equilibrium positions (n, 3), m, at p0 and at the optimized p (None when
    not computed); multiplier: bend stiffness multiplier per vertex (n,) at p (None without p);
    naive_sag, optimized_sag: the states' largest vertex displacement from q* over the strand length
    (NaN when not computed); note: what went wrong, if anything.
    """

    naive: np.ndarray | None
    optimized: np.ndarray | None
    multiplier: np.ndarray | None
    naive_sag: float
    optimized_sag: float
    note: str = ""


def strand_states(strand, p, problem_options: dict) -> StrandStates:
    """The naive and optimized static states of one strand (never raises: a failure is a note)."""
    nan = float("nan")
    try:
        problem = Problem(strand, **problem_options)
    except Exception as exc:  # noqa: BLE001 - reported on the page, the groom goes on
        return StrandStates(None, None, None, nan, nan, f"no model: {_detail(exc)}")
    notes: list[str] = []
    naive, naive_sag = _relax(problem, problem.p0, "naive", notes)
    p = None if p is None else np.asarray(p, dtype=float).reshape(-1)
    if p is None or p.size == 0 or not np.all(np.isfinite(p)):
        notes.append("no parameters")
        return StrandStates(naive, None, None, naive_sag, nan, "; ".join(notes))
    if p.size != problem.n_parameters:
        notes.append(f"its {p.size} parameters do not fit its problem ({problem.n_parameters})")
        return StrandStates(naive, None, None, naive_sag, nan, "; ".join(notes))
    optimized, optimized_sag = _relax(problem, p, "optimized", notes)
    interior = problem.physical(p)["bend_modulus"] / strand.youngs_modulus
    multiplier = np.r_[interior[0], interior, interior[-1]]
    return StrandStates(naive, optimized, multiplier, naive_sag, optimized_sag, "; ".join(notes))


def _relax(problem: Problem, p: np.ndarray, label: str, notes: list[str]) -> tuple[np.ndarray | None, float]:
    try:
        state = equilibrium(problem, p)
    except Exception as exc:  # noqa: BLE001
        notes.append(f"{label} static solve raised {_detail(exc)}")
        return None, float("nan")
    if not np.all(np.isfinite(state.positions)):
        notes.append(f"{label} static solve ended in a non-finite state")
        return None, float("nan")
    if not state.converged:
        notes.append(f"{label} static solve did not converge ({state.newton.message}); drawn where it stopped")
    return state.positions, state.relative_sag


def _detail(exc: Exception) -> str:
    return traceback.format_exception_only(type(exc), exc)[-1].strip()


def _unviewed(message: str) -> StrandStates:
    nan = float("nan")
    return StrandStates(None, None, None, nan, nan, message)


def view_states(strands, parameters, problem_options: dict | None = None, jobs: int | None = None,
                progress: bool = False, scheduler=None) -> list[StrandStates]:
    """``strand_states`` of every strand on ``jobs`` worker processes (frontend.batch.map_strands:
    None = all cores, 1 = in this process; ``scheduler`` as for ``sagfree.optimize``)."""
    options = check_problem_options(dict(problem_options or {}))
    strands, parameters = list(strands), list(parameters)
    if len(strands) != len(parameters):
        raise ValueError(f"{len(strands)} strands but {len(parameters)} parameter vectors")
    for strand in strands:  # load the compiled model once, here, so that forked workers start warm
        try:
            Problem(strand, **options)
            break
        except Exception:  # noqa: BLE001 - strand_states reports it
            continue
    return map_strands(strand_states, list(zip(strands, parameters)), (options,), jobs, progress, "static states",
                       _unviewed, scheduler)


def write_view(path, strands, parameters, problem_options: dict | None = None, status=None, messages=None,
               title: str = "sagfree view", jobs: int | None = None, progress: bool = False,
               scheduler=None) -> Path:
    """Write the interactive page of ``strands`` (module docstring) to ``path``; returns the path.

    parameters: one normalized parameter vector per strand (``Result.p``, ``ParameterFile.p``; None,
    empty or NaN where a strand has none); problem_options: the Problem options they were computed
    with (stiffness mode, bodies, ...; ``ParameterFile.problem_options``); status, messages: per
    strand (``Result.status`` / ``.message``; default "given" or "no parameters"); jobs, progress,
    scheduler: for the static solves (``view_states``).
    """
    options, strands = dict(problem_options or {}), list(strands)
    for name, values in (("status", status), ("messages", messages)):
        if values is not None and len(values) != len(strands):
            raise ValueError(f"{len(strands)} strands but {len(values)} {name}")
    bodies = [parse_body(b) for b in options.get("bodies") or ()]
    states = view_states(strands, parameters, options, jobs, progress, scheduler)
    if status is None:
        status = ["given" if s.optimized is not None else "no parameters" for s in states]
    messages = list(messages) if messages is not None else [""] * len(states)
    text = page(page_data(strands, states, bodies, list(status), messages, title,
                          options.get("stiffness", "element")))
    path = Path(path)
    write_bytes(path, text.encode("utf-8"))  # atomic, as every file sagfree writes
    return path


def page_data(strands, states: list[StrandStates], bodies, status: list[str], messages: list[str], title: str,
              stiffness: str = "element") -> dict:
    """The page's data (view_page.page): strands as integer coordinates (module docstring), per-strand
    records, the bodies' surfaces as mesh3d traces, titles."""
    counts, groomed, naive, optimized, multiplier = [], [], [], [], []
    has_naive, has_optimized = [], []
    for strand, state in zip(strands, states):
        points = np.asarray(getattr(strand, "points", np.zeros((0, 3))), dtype=float)
        if points.ndim != 2 or points.shape[1:] != (3,) or not np.all(np.isfinite(points)):
            points = np.zeros((0, 3))  # an unreadable strand: nothing to draw
        ints = _grid(points)
        counts.append(len(points))
        groomed.append(np.vstack([ints[:1], np.diff(ints, axis=0)]).ravel())
        for values, present, positions in ((naive, has_naive, state.naive),
                                           (optimized, has_optimized, state.optimized)):
            drawn = positions is not None and len(points) > 0 and np.shape(positions) == points.shape
            present.append(int(drawn))
            if drawn:
                values.append((_grid(positions) - ints).ravel())
        if has_optimized[-1]:
            multiplier.append(np.round(state.multiplier, 3))
    top = max([float(np.max(m)) for m in multiplier if m.size] + [1.0])
    drawn_status = [s if h or s == "no parameters" else f"{s} (no optimized state)"
                    for s, h in zip(status, has_optimized)]
    summary = _summary(status)
    return {
        "title": html.escape(title),
        "subtitle": html.escape(f"{len(counts)} strand{'s' if len(counts) != 1 else ''} ({summary}); "
                                f"stiffness={stiffness}"),
        "resolution": RESOLUTION,
        "counts": counts,
        "groomed": _flat(groomed),
        "naive": _flat(naive),
        "optimized": _flat(optimized),
        "hasNaive": has_naive,
        "hasOptimized": has_optimized,
        "multiplier": [float(v) for v in (np.concatenate(multiplier) if multiplier else [])],
        "status": [html.escape(s) for s in drawn_status],
        "note": [html.escape(_shortened("; ".join(t for t in (m if st != "converged" else "", s.note) if t)))
                 for st, m, s in zip(status, messages, states)],
        "maxMultiplier": [_finite(float(np.max(s.multiplier))) if s.multiplier is not None and s.multiplier.size
                          else None for s in states],
        "naiveSag": [_finite(s.naive_sag) for s in states],
        "optimizedSag": [_finite(s.optimized_sag) for s in states],
        "colourTitle": COLOUR_TITLES.get(stiffness, COLOUR_TITLES["element"]),
        "logMax": float(np.log10(max(top, 2.0))),
        "bodies": [body_trace(b) for b in bodies],
    }


def _grid(points) -> np.ndarray:
    return np.rint(np.asarray(points, dtype=float) / RESOLUTION).astype(np.int64)


def _flat(parts: list[np.ndarray]) -> list[int]:
    return np.concatenate(parts).tolist() if parts else []


#: characters of a strand's message kept on the page
NOTE_LENGTH = 300


def _shortened(text: str) -> str:
    return text if len(text) <= NOTE_LENGTH else text[: NOTE_LENGTH - 3] + "..."


def _finite(value: float):
    """``value`` to 4 significant digits, None for NaN (JSON)."""
    return float(f"{value:.4g}") if np.isfinite(value) else None


def _summary(status: list[str]) -> str:
    return ", ".join(f"{n} {s}" for s, n in Counter(status).items()) or "none"


#: resolution of the drawn spheres and capsules (rings along the axis, points around it)
RINGS, SEGMENTS = 24, 48


def body_trace(body) -> dict:
    """A plotly mesh3d trace of a body's surface: a Mesh's own triangles; a Sphere or a Capsule as
    a surface of revolution of RINGS x SEGMENTS (m, rounded to RESOLUTION)."""
    if isinstance(body, Mesh):
        vertices, faces, label = body.vertices, body.faces, f"{body.name} ({len(body.faces)} triangles)"
    elif isinstance(body, Sphere):
        polar = np.linspace(0.0, np.pi, RINGS + 1)
        vertices, faces = _revolved(body.center, np.array([0.0, 0.0, 1.0]), body.radius * np.sin(polar),
                                    -body.radius * np.cos(polar))
        label = f"{body.name} (r = {body.radius:g} m)"
    elif isinstance(body, Capsule):
        axis = body.b - body.a
        length = float(np.linalg.norm(axis))
        polar = np.r_[np.linspace(0.0, np.pi / 2, RINGS // 2 + 1), np.linspace(np.pi / 2, np.pi, RINGS // 2 + 1)]
        lift = np.r_[np.zeros(RINGS // 2 + 1), np.full(RINGS // 2 + 1, length)]
        vertices, faces = _revolved(body.a, axis / length, body.radius * np.sin(polar),
                                    lift - body.radius * np.cos(polar))
        label = f"{body.name} (r = {body.radius:g} m)"
    else:
        raise ValueError(f"cannot draw {body!r}: the page draws spheres, capsules and meshes")
    vertices = np.round(np.asarray(vertices, dtype=float), 7)
    return {"type": "mesh3d", "name": html.escape(label), "x": vertices[:, 0].tolist(),
            "y": vertices[:, 1].tolist(), "z": vertices[:, 2].tolist(), "i": faces[:, 0].tolist(),
            "j": faces[:, 1].tolist(), "k": faces[:, 2].tolist(), "color": "#e8c9a8", "opacity": 1.0,
            "flatshading": False, "hoverinfo": "name", "showlegend": True,
            "lighting": {"ambient": 0.6, "diffuse": 0.6, "specular": 0.1}}


def _revolved(origin, axis, radii, heights) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of the surface swept by the profile (radius, height along ``axis``)
    about ``axis`` through ``origin``: one ring of SEGMENTS points per profile point."""
    first = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    first /= np.linalg.norm(first)
    second = np.cross(axis, first)
    angle = np.linspace(0.0, 2 * np.pi, SEGMENTS, endpoint=False)
    around = np.cos(angle)[:, None] * first + np.sin(angle)[:, None] * second
    vertices = (np.asarray(origin, dtype=float) + heights[:, None, None] * axis
                + radii[:, None, None] * around[None]).reshape(-1, 3)
    ring, step = np.arange(len(radii) - 1)[:, None] * SEGMENTS, np.arange(SEGMENTS)[None]
    a, b = ring + step, ring + (step + 1) % SEGMENTS
    c, d = a + SEGMENTS, b + SEGMENTS
    faces = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3), np.stack([a, d, c], -1).reshape(-1, 3)])
    return vertices, faces
