"""Is the parameter problem of a root-held strand separable by statics? A measurement for issue 21.

    python benchmarks/study_vertex_decomposition.py [--strands 30] [--vertices 100]

At q* a vertex stencil's kinematics k (4D curvature and twist, 5 values) depend on its 11 DOFs
through 3 directions only: dk/dy has rank 3 (printed). So the 5 stresses dE/dk of a vertex act on
the DOFs through 3 combinations U^T dE/dk (U: dk/dy's left singular vectors), and with one stretch
force per edge the equilibrium f_ext = sum_e sigma_e dl_e/dy + sum_v (dk/dy)_v^T U_v s_v is a square
system for a strand held by its root alone: statics fix every s_v and sigma_e, whatever p is.

With the stretch parameters fixed, a vertex's stresses are beta (the bend multiplier, which also
scales the twist modulus) times a linear map D of its rest-shape change delta (rest curvature and
twist), so U^T D z = s_v fixes z = beta delta, and the vertex's share of R is
sum_j w_j (z_j / beta)^2 / 2 + w_beta (beta - 1)^2 / 2: convex in beta > 0, minimized on the interval
of multipliers whose delta = z / beta stays in its box. This script takes asc's edge parameters
(rest lengths and stretch multipliers), solves every vertex that way (a 3 x 3 solve and a scalar
root), and compares with the optimum asc reaches by Gauss-Newton (``start="linear"``; its default start
is solvers.statics_start, built on this): R, p and |c|_inf, and the time of both. The edges are not
separable this way: the rest lengths enter the bend energy's 1 / (lbar_{i-1} + lbar_i), and asc
uses them as a cheap stiffener (the root edge at its -5% bound); the interior edges' rest lengths
are held to ~1e-8 by their stretch forces, so only the root edge's joins its vertex
(solvers.statics_start; benchmarks/RESULTS.md, twelfth session).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import sagfree
from sagfree.formulation import dofs
from sagfree.formulation.problem import Problem
from sagfree.solvers import alm
from sagfree.solvers.statics_start import least_multiplier_scalar

#: slots of energies.VERTEX_PHYSICAL: rest curvature (2), rest twist, bend and twist moduli
REST_SLOTS, BEND_SLOT, TWIST_SLOT = (2, 3, 4), 5, 6


def effective_stresses(problem: Problem):
    """(U (S, 5, 3), vertex stresses s (S, 3), stretch forces sigma (n - 1)) that balance the
    external forces on the free DOFs, and the rank of each vertex's dk/dy."""
    _, kinematics_jacobian = problem.kinematics_at_rest  # (S, 11, 5): (dk/dy)^T
    stencils, n = kinematics_jacobian.shape[0], problem.n_vertices
    directions = np.empty((stencils, 5, 3))
    system = np.zeros((problem.q_star.size, 3 * stencils + n - 1))
    ranks = np.empty(stencils, dtype=int)
    for v in range(stencils):
        left, values, _ = np.linalg.svd(kinematics_jacobian[v].T)
        ranks[v] = int(np.sum(values > 1e-12 * values[0]))
        directions[v] = left[:, :3]
        system[np.ix_(problem.vertex_dofs[v], range(3 * v, 3 * v + 3))] += kinematics_jacobian[v] @ directions[v]
    positions, points = dofs.position_index(n), problem.strand.points
    for e in range(n - 1):
        tangent = (points[e + 1] - points[e]) / np.linalg.norm(points[e + 1] - points[e])
        system[positions[e], 3 * stencils + e] -= tangent
        system[positions[e + 1], 3 * stencils + e] += tangent
    rows = system[problem.free]
    acting = np.flatnonzero(np.any(rows != 0, axis=0))  # the root edge's stretch acts on no free DOF
    if len(acting) != rows.shape[0]:
        raise ValueError(f"{rows.shape[0]} free DOFs against {len(acting)} stresses: not a root-held strand")
    stresses = np.zeros(system.shape[1])
    stresses[acting] = np.linalg.solve(rows[:, acting], problem.external_forces[problem.free])
    return directions, stresses[:3 * stencils].reshape(stencils, 3), stresses[3 * stencils:], ranks


def vertices_given_edges(problem: Problem, p_edges: np.ndarray, statics) -> np.ndarray:
    """p with the edge entries of ``p_edges`` and every vertex's entries solved as the module
    docstring says (element stiffness, twist coupled to bend); statics: ``effective_stresses``."""
    layout = problem.layout
    p, w, lower, upper, p0 = layout.p0.copy(), layout.weights, layout.lower, layout.upper, layout.p0
    edge_entries = layout.edge_map.index[layout.edge_map.index >= 0]
    p[edge_entries] = p_edges[edge_entries]
    directions, stresses, _, _ = statics
    physical = problem.stencil_inputs(p, None, None)[1][3].copy()
    physical[:, BEND_SLOT], physical[:, TWIST_SLOT] = problem.strand.youngs_modulus, problem.strand.shear_modulus
    (jacobian,) = problem.vertex_fixed_functions.parameter_jacobian(problem.kinematics_at_rest[0],
                                                                    problem._vertex_geometry, physical)
    jacobian = jacobian.reshape(-1, 5, physical.shape[1])
    for v, slots in enumerate(layout.vertex_map.index):
        rest, bend = slots[list(REST_SLOTS)], slots[BEND_SLOT]
        z = np.linalg.solve(directions[v].T @ jacobian[v][:, list(REST_SLOTS)], stresses[v])  # beta * delta
        low = lower[bend]
        for zj, j in zip(z, rest):  # delta = z / beta inside its box
            if zj != 0.0:
                low = max(low, zj / ((upper[j] if zj > 0 else lower[j]) - p0[j]))
        beta = least_multiplier_scalar(float(np.sum(w[rest] * z**2)), w[bend], p0[bend], low, upper[bend])
        p[bend], p[rest] = beta, p0[rest] + z / beta
    return p


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--strands", type=int, default=30)
    parser.add_argument("--vertices", type=int, default=100)
    args = parser.parse_args()
    strands = sagfree.scenes.groom(args.strands, args.vertices, seed=0)
    alm.solve_alm(Problem(strands[0], stabilize=False), start="linear")  # load the compiled kernels first
    ranks, relative, moved, violation, times = [], [], [], [], {"asc": 0.0, "decomposed": 0.0}
    for strand in strands:
        problem = Problem(strand, stabilize=False)
        start = time.perf_counter()
        reference = alm.solve_alm(problem, start="linear")
        times["asc"] += time.perf_counter() - start
        start = time.perf_counter()
        statics = effective_stresses(problem)
        p = vertices_given_edges(problem, reference.p, statics)
        times["decomposed"] += time.perf_counter() - start
        ranks.extend(statics[3].tolist())
        relative.append(abs(problem.objective(p) / reference.objective - 1.0))
        moved.append(float(np.abs(p - reference.p).max()))
        violation.append(float(np.abs(problem.residual(p)).max()))
    print(f"groom({args.strands}, {args.vertices}, seed=0), per-element stiffness, no stabilization")
    counts = dict(zip(*(a.tolist() for a in np.unique(ranks, return_counts=True))))
    print(f"   rank of dk/dy per vertex stencil (rank: stencils): {counts}")
    print(f"   vertices solved apart, given asc's edge parameters: |R / R_asc - 1| <= {max(relative):.1e}, "
          f"|p - p_asc| <= {max(moved):.1e}, |c|_inf <= {max(violation):.1e}")
    print(f"   time per strand: asc {1e3 * times['asc'] / len(strands):.2f} ms, this prototype (a dense solve of "
          f"the statics, a Python loop over the vertices) {1e3 * times['decomposed'] / len(strands):.2f} ms")


if __name__ == "__main__":
    main()
