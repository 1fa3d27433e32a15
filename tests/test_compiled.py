"""Compiled stencil evaluation agrees with CasADi's virtual machine (the fallback), rounds alike on
every machine, and falls back to a portable build where the compiler refuses the machine's flags."""
import ctypes
import os
import subprocess

import casadi as ca
import numpy as np

from sagfree.formulation import compiled
from sagfree.formulation.compiled import BatchFunction, _source
from sagfree.formulation.stencils import edge_stencil, vertex_stencil


def test_compiled_and_virtual_machine_agree(rng):
    stencil = vertex_stencil("2d-slerp")
    assert stencil.parameter_jacobian.compiled  # the machine has a C compiler; CI must too
    fallback = BatchFunction(stencil.parameter_jacobian.function)
    args = [rng.standard_normal((7, 11)), rng.standard_normal((7, 13)), rng.uniform(1, 2, (7, 8)),
            rng.standard_normal((7, 7))]
    for a, b in zip(stencil.parameter_jacobian(*args), fallback(*args)):
        assert a.shape == b.shape
        assert np.allclose(a, b, rtol=1e-13, atol=1e-13)
    edge = edge_stencil()
    y = rng.standard_normal((5, 6))
    assert np.allclose(edge.geometry(y)[0], np.linalg.norm(y[:, 3:] - y[:, :3], axis=1), rtol=1e-15)
    assert edge.energy(np.empty((0, 6)), np.empty((0, 2)), np.empty((0, 2)))[0].shape == (0,)


def _portable_twin(function, tmp_path) -> BatchFunction:
    """``function`` built by the portable command (without MACHINE_FLAGS), outside the cache."""
    c_file, library = tmp_path / "portable.c", tmp_path / "portable.so"
    c_file.write_text(_source([function]))
    subprocess.run([os.environ.get("CC", "cc"), "-O2", "-fPIC", "-shared", "-o", str(library), str(c_file), "-lm"], check=True)
    return BatchFunction(function, getattr(ctypes.CDLL(str(library)), f"{function.name()}_batch"))


def test_machine_build_rounds_like_the_portable_one(rng, tmp_path):
    """MACHINE_FLAGS keep every operation's rounding (no fused multiply-adds): the same bits as a
    portable -O2 build, so results do not depend on the machine a strand was solved on."""
    stencil = vertex_stencil("4d")
    args = [rng.standard_normal((50, 11)), rng.standard_normal((50, 13)), rng.uniform(1, 2, (50, 8)),
            rng.standard_normal((50, 7))]
    portable = _portable_twin(stencil.parameter_jacobian.function, tmp_path)
    for a, b in zip(stencil.parameter_jacobian(*args), portable(*args)):
        assert np.array_equal(a, b)


def test_a_compiler_without_machine_flags_gets_the_portable_build(tmp_path, monkeypatch):
    refusing = tmp_path / "cc-refusing"
    refusing.write_text('#!/bin/sh\nfor a in "$@"; do [ "$a" = "-march=native" ] && exit 1; done\nexec cc "$@"\n')
    refusing.chmod(0o755)
    monkeypatch.setenv("CC", str(refusing))
    monkeypatch.setenv("SAGFREE_CACHE", str(tmp_path / "cache"))
    x = ca.SX.sym("x", 2)
    (product,) = compiled.batch_functions([ca.Function("refused_flags_product", [x], [x[0] * x[1] + x[0]])])
    assert product.compiled
    assert np.array_equal(product(np.array([[2.0, 3.0], [4.0, 0.5]]))[0], [8.0, 6.0])


def test_the_cache_key_holds_the_machine(monkeypatch):
    """A library built with -march=native on one CPU is never loaded on another (a shared cache)."""
    here = compiled._library("int f;", "stencils")
    monkeypatch.setattr(compiled, "cpu_identity", lambda: "another cpu")
    assert compiled._library("int f;", "stencils") != here
