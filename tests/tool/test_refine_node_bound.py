"""Regression (issue 12): the adaptive loop on the R 3 / R 30 punch at t = 0.01 mm must not
over-refine. Pass 2 went from 406 to 5 474 nodes (6.5e-4 mm, 15x below t): the marks that
`refine._mapped_border_marks` put on the border of the corner blends' mapped faces asked the
factor times the blends' 1.6 mm R 3 edges, not their 6.7 mm sweep edges the error law refers
to, and the graded marks spread that over whole mapped sides.

References: the node bound is the Nagata error law e = C h^4 / R^3 integrated over the
punch's analytic faces (their areas and principal curvatures from its dimensions, not from
the mesh); the error bound t is measured by OpenCASCADE (GeomAPI_ProjectPointOnSurf) at the
patches of the 4 worst elements on a grid denser than the loop's check.
"""

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parents[2] / "benchmarks"))

TOL = 0.01


def law_nodes(tol: float, h_max: float) -> float:
    """Elements (about the nodes) of an isotropic mesh sized everywhere by the law
    h = (tol / (C k_p^3))^(1/4) (`sizing.patch_curvature`, at most 60 degrees of normal turn,
    h_max on planes): sum of area / h^2 over the punch's faces (box 120 x 80 x 30, vertical
    edges R 30, top edges R 3; the bottom is not in the file)."""
    from cadbridge.mesh.sizing import NAGATA_ERROR_CONSTANT as C

    def h(kp: float, kmax: float) -> float:
        return min((tol / (C * kp ** 3)) ** 0.25, math.pi / 3 / kmax, h_max)

    r, R, height = 3.0, 30.0, 30.0
    straight = 2 * (120 - 2 * R) + 2 * (80 - 2 * R)  # length of the straight top edges
    tube = R - r  # the corner blends: tube r about a sweep of radius R - r
    faces = [
        (straight * math.pi / 2 * r, h(1 / r, 1 / r)),  # R 3 fillets (cylinders)
        (4 * math.pi / 2 * R * (height - r), h(1 / R, 1 / R)),  # R 30 vertical rounds
        # corner blends (quarter tori): area r (pi/2) (tube pi/2 + r), their worst k_p (outer equator)
        (4 * r * math.pi / 2 * (tube * math.pi / 2 + r),
         h(np.cbrt(max(1 / r ** 3 + 1 / R ** 3, (1 / r + 1 / R) ** 3 / 2)), 1 / r)),
        ((120 - 2 * r) * (80 - 2 * r) - (4 - math.pi) * tube ** 2, h_max),  # top plane
        (straight * (height - r), h_max),  # side planes
    ]
    return sum(a / hh ** 2 for a, hh in faces)


@pytest.fixture(scope="module")
def punch(tmp_path_factory):
    pytest.importorskip("cadquery")
    import bench_adaptive

    path = tmp_path_factory.mktemp("punch") / "punch_r3_r30_nurbs.igs"
    bench_adaptive.make_punch(path)
    return path


def test_punch_at_0_01_is_not_over_refined(punch):
    from cadbridge.iges import read_iges
    from cadbridge.tool.build import CadProjector
    from cadbridge.tool.refine import refine_mesh, shape_check
    from tests.tool.test_refine import occ_max_error_at_worst

    model = read_iges(punch)
    projector = CadProjector(model)
    r = refine_mesh(punch, TOL, model=model, projector=projector)
    assert r.met
    # one halving of every element of the law's isotropic mesh (the loop's normal-turn step,
    # factor 0.5 per direction) is the most the loop may spend; the regression had 17x
    n_law = law_nodes(TOL, model.size() / 4.0)  # refine_mesh's default largest size
    nodes = len(r.mesh.nodes)
    assert nodes <= n_law / 0.5 ** 2, (nodes, n_law)
    # ... and no element is refined for nothing: the error is used, not 15x below t
    assert r.check["max_error"] > TOL / 4
    # the error on a grid denser than the check's (11): OCC at the 4 worst elements' patches
    # on 16 divisions, cadbridge's measure on 16 divisions everywhere
    c, per = shape_check(r.tools, model, projector, 16)
    assert c["max_error"] <= TOL
    assert occ_max_error_at_worst(r, punch, per, 16) <= TOL
