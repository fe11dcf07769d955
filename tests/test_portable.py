"""pipeline.portable: CPU-independent transcendentals and tie-robust choices, and the rule that keeps the pipeline
free of arithmetic whose last bits change with the CPU (docs/evaluation.md, "Same numbers on every machine")."""
from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from pipeline import portable

PIPELINE = Path(__file__).resolve().parents[1] / "pipeline"


# ---------------------------------------------------------------------------------------------------------------
# the functions


def test_transcendentals_are_the_c_library_s_bit_for_bit():
    rng = np.random.default_rng(0)
    x = rng.uniform(-30.0, 30.0, 5000)
    y = rng.uniform(-3.0, 3.0, 5000)
    pos = np.abs(x) + 1e-300
    assert np.array_equal(portable.exp(x), [math.exp(v) for v in x])
    assert np.array_equal(portable.log(pos), [math.log(v) for v in pos])
    assert np.array_equal(portable.log1p(pos), [math.log1p(v) for v in pos])
    assert np.array_equal(portable.atan2(y, x), [math.atan2(a, b) for a, b in zip(y, x)])


def test_log_edges_are_numpy_s_without_warnings():
    with np.errstate(all="raise"):
        out = portable.log(np.array([0.0, -1.0, 1.0, np.inf]))
        out1p = portable.log1p(np.array([-1.0, -2.0, 0.0]))
    assert out[0] == -np.inf and np.isnan(out[1]) and out[2] == 0.0 and out[3] == np.inf
    assert out1p[0] == -np.inf and np.isnan(out1p[1]) and out1p[2] == 0.0


@pytest.mark.parametrize("values", [[0.0], [-np.inf, -np.inf], [-1e308, -1e308], [1000.0, 1000.0, -1000.0],
                                    [-745.2, -745.3]])
def test_logsumexp_is_finite_and_exact_where_it_can_be(values):
    a = np.array(values)
    out = float(portable.logsumexp(a))
    if np.all(a == -np.inf):
        assert out == -np.inf
    else:
        top = a.max()
        assert math.isfinite(out)
        assert out == pytest.approx(top + math.log(sum(math.exp(v - top) for v in a)), rel=1e-15, abs=1e-12)


def test_logsumexp_along_an_axis_and_empty():
    a = np.log(np.array([[1.0, 3.0], [2.0, 2.0]]))
    assert np.allclose(portable.logsumexp(a, axis=1), np.log([4.0, 4.0]))
    assert np.allclose(portable.logsumexp(a, axis=0), np.log([3.0, 5.0]))
    assert portable.logsumexp(np.array([])) == -np.inf


def test_argmin_tolerant_breaks_near_ties_by_index():
    assert portable.argmin_tolerant([1.0 + 1e-15, 1.0, 2.0], 1e-9) == 0  # a last-bit tie: the lower index
    assert portable.argmin_tolerant([1.0 + 1e-6, 1.0, 2.0], 1e-9) == 1  # a real difference: the smaller
    assert portable.argmin_tolerant([np.nan, np.inf, 3.0], 1e-9) == 2
    assert portable.argmin_tolerant([np.nan, np.inf], 1e-9) == -1
    assert portable.argmin_tolerant([5.0], 1e-9) == 0


def test_tie_key_makes_last_bit_neighbours_equal_and_sorts_nan_last():
    v = np.array([0.3, np.nextafter(0.3, 1.0), 0.3 + 1e-6, np.nan, -np.inf])
    k = portable.tie_key(v, 1e-9)
    assert k[0] == k[1] and k[2] > k[1] and k[3] == np.inf and k[4] == -np.inf
    order = np.lexsort((np.arange(len(v)), k))
    assert list(order) == [4, 0, 1, 2, 3]


# ---------------------------------------------------------------------------------------------------------------
# the rule: nothing in pipeline/ computes through BLAS/LAPACK or numpy's SIMD-dispatched transcendentals

#: numpy functions whose float64 results change with the CPU: BLAS/LAPACK kernels or SIMD dispatch (AVX-512 SVML
#: and AVX512F implementations against glibc's), measured on this project's machine (docs/evaluation.md).
FORBIDDEN_NUMPY = {"dot", "vdot", "inner", "matmul", "tensordot", "einsum", "exp", "log", "log1p", "expm1", "log2",
                   "log10", "exp2", "arctan2", "arctan", "arcsinh", "tanh", "power", "float_power", "logaddexp"}
#: Modules that only draw figures (matplotlib), where a last bit cannot reach a table.
FIGURE_MODULES = {"figures.py", "studies/training_figure.py", "studies/pareto.py", "studies/retrieval_ladder_report.py"}


def _violations(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        where = f"{path.relative_to(PIPELINE)}:{getattr(node, 'lineno', 0)}"
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
            found.append(f"{where}: matrix product '@'")
        elif isinstance(node, ast.Attribute):
            chain = []
            cur = node
            while isinstance(cur, ast.Attribute):
                chain.append(cur.attr)
                cur = cur.value
            if isinstance(cur, ast.Name):
                chain.append(cur.id)
            chain = chain[::-1]
            if chain[:1] == ["np"] and len(chain) == 2 and chain[1] in FORBIDDEN_NUMPY:
                found.append(f"{where}: np.{chain[1]}")
            if chain[:2] == ["np", "linalg"] and len(chain) == 3 and chain[2] != "norm":
                found.append(f"{where}: np.linalg.{chain[2]}")
            if chain[-1:] == ["dot"] and chain[:1] != ["np"]:
                found.append(f"{where}: .dot()")
        elif isinstance(node, ast.Call):
            f = node.func
            if (isinstance(f, ast.Attribute) and f.attr == "norm" and isinstance(f.value, ast.Attribute)
                    and f.value.attr == "linalg" and not any(k.arg == "axis" for k in node.keywords)
                    and len(node.args) < 3):
                found.append(f"{where}: np.linalg.norm without axis (a BLAS dot for vectors)")
        elif isinstance(node, ast.ImportFrom) and node.module in ("scipy.special", "scipy.linalg", "numpy.linalg"):
            names = {a.name for a in node.names}
            if node.module != "scipy.special" or names & {"logsumexp", "expit", "softmax", "log_softmax"}:
                found.append(f"{where}: from {node.module} import {', '.join(sorted(names))}")
    return found


def test_no_stage_computes_through_blas_or_simd_dispatched_transcendentals():
    bad = []
    for path in sorted(PIPELINE.rglob("*.py")):
        rel = str(path.relative_to(PIPELINE))
        if rel in FIGURE_MODULES or rel == "portable.py":
            continue
        bad.extend(_violations(path))
    assert not bad, ("use pipeline.geometry.rotate/dot2, pipeline.spd or pipeline.portable instead:\n"
                     + "\n".join(bad))


#: SHA-256 of the 1 mm Panda grid's values (float64, C order) built by Open3D's raycasting from pybullet's meshes
#: with the locked environment. Open3D computes it in float32 (Embree picks SIMD kernels by CPU): this pins it, so
#: a machine that built another grid fails here instead of tracking with different numbers.
PANDA_GRID_SHA256 = "9395bdd8158d1966983f4e61a0cc39b2a38562548ce5d2ad9c74379fdbe99a6f"


def test_the_panda_grid_is_the_same_on_this_machine():
    import hashlib

    from pipeline.robot.panda_mesh import build_panda_grid

    grid = build_panda_grid(0.001)
    assert grid.values.shape == (140, 206)
    assert hashlib.sha256(np.ascontiguousarray(grid.values).tobytes()).hexdigest() == PANDA_GRID_SHA256
