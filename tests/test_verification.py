"""`sagfree check`: AD vs hand-derived vs finite differences for every term, block and variant."""
import numpy as np

import sagfree
from sagfree.cli import main
from sagfree.formulation import hand_derived, verification
from sagfree.formulation.curvature import VARIANTS
from sagfree.formulation.parameters import BLOCKS, STRAND_BLOCK


def test_every_term_block_and_variant_is_verified_and_passes():
    rows = verification.verify()
    assert all(r.passed for r in rows), [r for r in rows if not r.passed]
    covered = {(r.term, r.quantity, r.variant) for r in rows}
    for variant in VARIANTS:
        for block in (*BLOCKS, STRAND_BLOCK, "force"):
            assert ("bend", block, variant) in covered
    for term in ("stretch", "twist"):
        for block in (*BLOCKS, STRAND_BLOCK, "force"):
            assert (term, block, "any") in covered
    assert ("contact", "contact_force", "any") in covered
    # the checks are not vacuous: the dependent blocks have nonzero Jacobians that were compared
    assert not any(r.structural_zero for r in rows if r.quantity in verification.TERM_BLOCKS[r.term])


def test_a_wrong_hand_formula_fails_the_check(monkeypatch):
    true_jacobian = hand_derived.parameter_jacobian

    def off_by_sign_on_twist(problem, p, term, q=None, frames=None):
        jac = true_jacobian(problem, p, term, q, frames)
        if "rest_twist" in problem.blocks:
            jac[:, problem.blocks["rest_twist"]] *= -1
        return jac

    monkeypatch.setattr(hand_derived, "parameter_jacobian", off_by_sign_on_twist)
    rows = verification.verify(variants=("4d",))
    failed = {(r.term, r.quantity) for r in rows if not r.passed}
    assert failed == {("twist", "rest_twist")}


def test_jacobian_error_detects_a_wrong_jacobian(rng):
    pb = sagfree.Problem(sagfree.scenes.helix(n=12))
    p = verification.perturbed_parameters(pb, rng)
    true_jacobian = pb.jacobian
    pb.jacobian = lambda q: 1.001 * true_jacobian(q)
    assert verification.jacobian_error(pb, p, "rest_length") > 1e-4


def test_check_command_prints_the_table_and_exits_by_result(capsys, monkeypatch):
    assert main(["check", "--variant", "2d-slerp"]) == 0
    out = capsys.readouterr().out
    assert "bend     rest_curvature" in out and "2d-slerp" in out and "passed" in out
    bad = verification.CheckRow("bend", "rest_curvature", "4d", 1.0, 0.0)
    monkeypatch.setattr(verification, "verify", lambda **kw: [bad])
    assert main(["check"]) == 1
    assert "FAIL" in capsys.readouterr().out


def test_hand_derived_matches_ad_at_a_moved_state_with_reference_twist(rng):
    strand = verification.verification_strands(seed=5)["twisted"]
    for variant in VARIANTS:
        pb = sagfree.Problem(strand, curvature=variant)
        p = verification.perturbed_parameters(pb, rng)
        q = pb.q_star + 0.05 * rng.standard_normal(pb.q_star.size) * 5e-3
        frames = sagfree.formulation.frames.transport_frames(pb.frames, sagfree.formulation.dofs.positions(q))
        assert np.abs(frames.reference_twist).max() > 1e-3
        hand = sum(hand_derived.gradient(pb, p, term, q, frames) for term in ("stretch", "bend", "twist"))
        ad = pb.elastic_gradient(p, q, frames)
        assert np.abs(hand - ad).max() <= 1e-10 * np.abs(ad).max()
