"""Energy terms: gradients against finite differences, and known values."""

import numpy as np
import pytest

from perception.energy import (
    BoundaryTerm,
    CorrespondenceTerm,
    DepthTerm,
    HoldTerm,
    MotionPriorTerm,
    OutsideTerm,
    PlaneDepthTerm,
    SmoothnessTerm,
    StretchTerm,
)
from perception.geometry import backproject, project
from perception.mesh import barycentric_matrix, rectangle_mesh

K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def mesh_vertices(rng, z=1.2):
    m = rectangle_mesh(0.3, 0.24, 0.03)
    V = m.canonical - [0.15, 0.12, 0.0]
    V[:, 2] = z + 0.05 * np.sin(4 * V[:, 0]) + rng.normal(0, 0.003, len(V))
    return m, V


def numeric_gradient(term, V, eps=1e-7, n_check=40, rng=None):
    rng = rng or np.random.default_rng(0)
    idx = rng.choice(len(V), size=min(n_check, len(V)), replace=False)
    g = np.zeros((len(idx), 3))
    for a, i in enumerate(idx):
        for c in range(3):
            Vp, Vm = V.copy(), V.copy()
            Vp[i, c] += eps
            Vm[i, c] -= eps
            g[a, c] = (term.evaluate(Vp)[0] - term.evaluate(Vm)[0]) / (2 * eps)
    return idx, g


def check_gradient(term, V):
    _, grad = term.evaluate(V)
    idx, g = numeric_gradient(term, V)
    scale = max(np.abs(g).max(), 1e-9)
    np.testing.assert_allclose(grad[idx], g, atol=1e-4 * scale + 1e-10)
    assert np.abs(grad).max() > 0  # the check is not vacuous


def test_data_terms_share_a_pixel_look_up_only_for_the_same_vertices_and_camera():
    # The depth, boundary and outside terms look a V up once between them; a term with
    # another camera, or the same V's copy, must get its own answer, not the last one.
    rng = np.random.default_rng(5)
    _, V = mesh_vertices(rng)
    range_m = np.tile(np.linspace(1.0, 1.4, 640, dtype=np.float32), (480, 1))  # each column its own range
    moved = K.copy()
    moved[0, 2] += 40.0  # the same image seen 40 px to the side
    here = DepthTerm(range_m, K, outlier_m=1.0)
    there = DepthTerm(range_m, moved, outlier_m=1.0)
    e_here, e_there = here.evaluate(V)[0], there.evaluate(V)[0]
    assert e_here != pytest.approx(e_there, rel=1e-3)
    assert DepthTerm(range_m, K, outlier_m=1.0).evaluate(V.copy())[0] == pytest.approx(e_here, rel=1e-12)
    assert DepthTerm(range_m, moved, outlier_m=1.0).evaluate(V.copy())[0] == pytest.approx(e_there, rel=1e-12)


def test_smoothness_gradient_and_value():
    rng = np.random.default_rng(1)
    m, V = mesh_vertices(rng)
    term = SmoothnessTerm(m.stiffness())
    check_gradient(term, V)
    kc = m.k_col()
    e, _ = term.evaluate(V)
    assert e == pytest.approx(0.5 * np.sum((kc @ V) ** 2), rel=1e-12)  # eq. 9 equals eq. 10


def test_correspondence_gradient_and_weights():
    rng = np.random.default_rng(2)
    m, V = mesh_vertices(rng)
    fid = rng.integers(0, len(m.faces), 60)
    bary = rng.dirichlet([1, 1, 1], 60)
    B = barycentric_matrix(fid, bary, m.faces, m.n_vertices)
    targets = B @ V + rng.normal(0, 0.01, (60, 3))
    w = (rng.random(60) > 0.3).astype(float)
    term = CorrespondenceTerm(B, targets, w)
    check_gradient(term, V)
    e, _ = term.evaluate(V)
    assert e == pytest.approx(0.5 * np.sum(w * np.sum((B @ V - targets) ** 2, axis=1)))
    # zero when every target sits on its mesh point
    assert CorrespondenceTerm(B, B @ V, np.ones(60)).evaluate(V)[0] == pytest.approx(0.0, abs=1e-20)


def range_image_of_plane(z):
    h, w = 480, 640
    uu, vv = np.meshgrid(np.arange(w), np.arange(h))
    rays = np.stack([(uu - K[0, 2]) / K[0, 0], (vv - K[1, 2]) / K[1, 1], np.ones_like(uu, float)], -1)
    return (z * np.linalg.norm(rays, axis=-1)).astype(np.float32)


def test_depth_gradient_is_along_the_ray():
    rng = np.random.default_rng(3)
    m, V = mesh_vertices(rng)
    term = DepthTerm(range_image_of_plane(1.25), K, outlier_m=0.5)
    check_gradient(term, V)
    _, grad = term.evaluate(V)
    cos = np.abs(np.einsum("ij,ij->i", grad, V)) / (np.linalg.norm(grad, axis=1) * np.linalg.norm(V, axis=1))
    assert np.all(cos[np.linalg.norm(grad, axis=1) > 0] > 1 - 1e-9)


def tilted_plane_depth(slope=0.8, z0=1.25):
    """(H, W) depth of the plane z = z0 + slope * x, seen steeply (as a lifted cloth is)."""
    h, w = 480, 640
    uu, _ = np.meshgrid(np.arange(w), np.arange(h))
    x_over_z = (uu - K[0, 2]) / K[0, 0]
    return (z0 / (1.0 - slope * x_over_z)).astype(np.float32)


def test_plane_depth_gradient_and_it_pulls_along_the_surface_normal():
    from perception.energy import measured_surface

    rng = np.random.default_rng(8)
    _, V = mesh_vertices(rng)
    term = PlaneDepthTerm(*measured_surface(tilted_plane_depth(), K), K, outlier_m=0.5)
    check_gradient(term, V)
    normal = np.array([-0.8, 0.0, 1.0]) / np.hypot(0.8, 1.0)  # of z = 1.25 + 0.8 x
    _, grad = term.evaluate(V)
    pulled = np.linalg.norm(grad, axis=1) > 0
    assert pulled.sum() > 0.9 * len(V)
    cos = np.abs(grad[pulled] @ normal) / np.linalg.norm(grad[pulled], axis=1)
    assert np.all(cos > 1 - 1e-6)  # along the normal, where the ray residual would pull along the ray
    # the residual is the distance to the plane
    on = np.array([[0.1, 0.05, 1.25 + 0.8 * 0.1]])
    r, active, _ = term.lookup(on + 0.01 * normal)
    assert active[0] and r[0] == pytest.approx(0.01, rel=1e-3)


def test_depth_residual_is_distance_along_ray_and_outliers_ignored():
    uv = np.array([[100.0, 50.0], [320.0, 240.0], [600.0, 400.0]])
    on_surface = backproject(uv, np.full(3, 1.25), K)
    term = DepthTerm(range_image_of_plane(1.25), K, outlier_m=0.1)
    assert term.evaluate(on_surface)[0] == pytest.approx(0.0, abs=1e-10)
    moved = on_surface * 1.04  # 4 % further along each ray
    r, active, _ = term.lookup(moved)
    np.testing.assert_allclose(r, 0.04 * np.linalg.norm(on_surface, axis=1), rtol=1e-5)
    far = on_surface * 1.5
    assert not term.lookup(far)[1].any()  # beyond outlier_m: no force


def test_depth_missing_contributes_nothing():
    rng = np.random.default_rng(4)
    _, V = mesh_vertices(rng)
    term = DepthTerm(np.zeros((480, 640), np.float32), K, outlier_m=0.5)
    e, g = term.evaluate(V)
    assert e == 0.0 and not g.any()


def outline_square(z, half=0.1, n=200):
    t = np.linspace(-half, half, n)
    pts = np.concatenate([np.column_stack([t, np.full(n, -half)]), np.column_stack([t, np.full(n, half)]),
                          np.column_stack([np.full(n, -half), t]), np.column_stack([np.full(n, half), t])])
    outline = np.column_stack([pts, np.full(len(pts), z)])
    # object mask: the square's image
    uv = project(np.array([[-half, -half, z], [half, half, z]]), K)
    mask = np.zeros((480, 640), bool)
    mask[int(uv[0, 1]) : int(uv[1, 1]) + 1, int(uv[0, 0]) : int(uv[1, 0]) + 1] = True
    return outline, mask


def test_depth_pulls_only_the_vertices_it_may():
    rng = np.random.default_rng(5)
    _, V = mesh_vertices(rng)
    allowed = rng.random(len(V)) < 0.5
    term = DepthTerm(range_image_of_plane(1.25), K, outlier_m=0.5, vertex_mask=allowed)
    check_gradient(term, V)
    _, grad = term.evaluate(V)
    pull = np.linalg.norm(grad, axis=1)
    assert pull[~allowed].max() == 0 and pull[allowed].min() > 0


def test_motion_prior_gradient_and_what_it_keeps():
    rng = np.random.default_rng(6)
    m, V = mesh_vertices(rng)
    prior = V + rng.normal(0, 0.01, V.shape)
    hidden = m.material_xy[:, 0] > 0.2
    term = MotionPriorTerm.around(m.edges(), hidden, prior)
    check_gradient(term, V)
    # The prior's shape moved rigidly costs only the anchor; observed vertices alone cost nothing.
    shifted = prior + [0.02, -0.01, 0.03]
    e_shift, _ = term.evaluate(shifted)
    assert e_shift == pytest.approx(0.5 * 0.05 * hidden.sum() * (0.02**2 + 0.01**2 + 0.03**2))
    moved_seen = prior.copy()
    far = m.material_xy[:, 0] < 0.1  # observed and not next to a hidden vertex
    moved_seen[far] += 0.05
    assert term.evaluate(moved_seen)[0] == pytest.approx(0.0, abs=1e-15)
    squeezed = prior.copy()
    squeezed[hidden, 0] = prior[hidden, 0].min() + 0.5 * (prior[hidden, 0] - prior[hidden, 0].min())
    assert term.evaluate(squeezed)[0] > 1e-4  # compressing the hidden part costs
    H = term.gauss_newton(V)
    P = rng.normal(size=V.shape)
    np.testing.assert_allclose(H(P), term.evaluate(V + P)[1] - term.evaluate(V)[1], atol=1e-12)  # exact: quadratic


def test_stretch_gradient_and_what_it_resists():
    rng = np.random.default_rng(7)
    m, V = mesh_vertices(rng)
    edges = m.edges()
    rest = np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1)
    term = StretchTerm(edges, rest)
    moved = V + rng.normal(0, 0.004, V.shape)
    check_gradient(term, moved)
    # free of cost at rest and under any rigid motion; a uniform shrink costs
    assert term.evaluate(V)[0] == pytest.approx(0.0, abs=1e-20)
    c, s = np.cos(0.4), np.sin(0.4)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    assert term.evaluate(V @ R.T + [0.1, -0.2, 0.3])[0] == pytest.approx(0.0, abs=1e-18)
    centre = V.mean(axis=0)
    shrunk = centre + 0.8 * (V - centre)
    assert term.evaluate(shrunk)[0] == pytest.approx(0.5 * np.sum((0.2 * rest) ** 2), rel=1e-9)
    # Gauss-Newton: J^T J P, with J the edge directions: matches the gradient's change for a small step at rest
    H = term.gauss_newton(V)
    P = 1e-6 * rng.normal(size=V.shape)
    change = term.evaluate(V + P)[1] - term.evaluate(V)[1]
    np.testing.assert_allclose(H(P), change, atol=1e-3 * np.abs(change).max())


def test_hold_gradient_and_value():
    rng = np.random.default_rng(8)
    m, V = mesh_vertices(rng)
    ids = np.array([0, 5, 5])
    points = V[ids] + rng.normal(0, 0.02, (3, 3))
    term = HoldTerm(ids, points)
    check_gradient(term, V)
    e, g = term.evaluate(V)
    assert e == pytest.approx(0.5 * np.sum((V[ids] - points) ** 2))
    untouched = np.setdiff1d(np.arange(len(V)), ids)
    assert not g[untouched].any()
    H = term.gauss_newton(V)
    P = rng.normal(size=V.shape)
    np.testing.assert_allclose(H(P), term.evaluate(V + P)[1] - term.evaluate(V)[1], atol=1e-12)  # exact: quadratic


def test_boundary_gradient_and_sign():
    rng = np.random.default_rng(5)
    outline, mask = outline_square(1.2)
    # boundary vertices scattered around the square's edge, inside and outside
    ang = rng.uniform(0, 2 * np.pi, 30)
    V = np.column_stack([0.1 * np.sign(np.cos(ang)) + rng.normal(0, 0.01, 30),
                         0.1 * np.sin(ang), np.full(30, 1.2) + rng.normal(0, 0.005, 30)])
    ids = np.arange(30)
    term = BoundaryTerm(ids, np.full(30, 0.004), outline, mask, K, gate_m=0.05)
    check_gradient(term, V)
    s, _, sign, active = term.signed_distance(V)
    inside = np.abs(V[:, 0] / V[:, 2]) < 0.1 / 1.2
    clear = active & (np.abs(np.abs(V[:, 0] / V[:, 2]) - 0.1 / 1.2) > 3 / 500)  # more than 3 px from the edge
    assert clear.sum() > 10
    np.testing.assert_array_equal(sign[clear] > 0, inside[clear])


def test_boundary_pulls_outside_vertex_inward():
    outline, mask = outline_square(1.2)
    V = np.array([[0.13, 0.0, 1.2]])  # 3 cm outside the right edge
    term = BoundaryTerm(np.array([0]), np.array([0.01]), outline, mask, K, gate_m=0.1)
    _, g = term.evaluate(V)
    assert g[0, 0] > 0  # descent (-g) moves it toward -x, back inside
    e, _ = term.evaluate(V)
    assert e == pytest.approx(0.5 * (0.03 + 0.01) ** 2, rel=1e-3)


def test_boundary_leaves_alone_the_vertices_nearest_a_hidden_stretch_of_the_contour():
    """Something nearer hides the square's right edge from y = -0.05 to 0.05. A vertex on that
    stretch is nearest to the ends of the gap in the outline, 5 cm along the edge, and would be
    pulled along it; with the hidden stretch known it is left alone. Vertices nearer the
    outline than the hidden stretch are pulled as before."""
    outline, mask = outline_square(1.2)
    gap = (np.abs(outline[:, 0] - 0.1) < 1e-9) & (np.abs(outline[:, 1]) < 0.05)
    V = np.array([[0.1, 0.0, 1.2], [0.1, 0.01, 1.2], [0.13, -0.08, 1.2]])  # on the gap, and off a seen stretch
    ids = np.arange(3)
    blind = BoundaryTerm(ids, np.zeros(3), outline[~gap], mask, K, gate_m=0.06)
    assert blind.signed_distance(V)[3][:2].all() and np.abs(blind.evaluate(V)[1][:2, 1]).min() > 0.03
    term = BoundaryTerm(ids, np.zeros(3), outline[~gap], mask, K, gate_m=0.06, hidden_points=outline[gap])
    _, grad = term.evaluate(V)
    np.testing.assert_array_equal(term.signed_distance(V)[3], [False, False, True])
    assert np.all(grad[:2] == 0) and grad[2, 0] > 0
    check_gradient(term, V)


def test_outside_pulls_seen_vertices_off_the_object_to_its_outline_and_no_others():
    rng = np.random.default_rng(6)
    outline, mask = outline_square(1.2)
    # vertices spread over twice the square: about three quarters project off the object
    V = np.column_stack([rng.uniform(-0.2, 0.2, 60), rng.uniform(-0.2, 0.2, 60), np.full(60, 1.2)])
    seen = rng.random(60) < 0.8
    term = OutsideTerm(outline, mask, K, seen)
    check_gradient(term, V)
    _, grad = term.evaluate(V)
    off = np.maximum(np.abs(V[:, 0]), np.abs(V[:, 1])) > 0.1 + 3 * 1.2 / 500  # more than 3 px outside
    on = np.maximum(np.abs(V[:, 0]), np.abs(V[:, 1])) < 0.1 - 3 * 1.2 / 500
    pull = np.linalg.norm(grad, axis=1)
    assert (off & seen).sum() > 10 and (on & seen).sum() > 3
    assert pull[off & seen].min() > 0 and pull[on].max() == 0 and pull[~seen].max() == 0
    # the pull is the offset from the nearest outline point: a vertex 5 cm right of the square
    e, g = OutsideTerm(outline, mask, K, np.ones(1, bool)).evaluate(np.array([[0.15, 0.0, 1.2]]))
    assert e == pytest.approx(0.5 * 0.05 ** 2, rel=1e-3)
    assert g[0, 0] > 0  # descent (-g) moves it toward -x, onto the object


def test_outside_leaves_vertices_on_pixels_without_depth_where_they_are():
    # a cloth seen at a grazing angle loses its depth and so falls out of the segmented
    # object: a vertex there is not known to be off the object, and is not pulled
    outline, mask = outline_square(1.2)
    measured = np.ones(mask.shape, bool)
    measured[:, 320 + int(0.12 / 1.2 * 500):] = False  # no depth from 12 cm right of the centre on
    V = np.array([[0.11, 0.0, 1.2], [0.15, 0.0, 1.2], [-0.15, 0.0, 1.2]])  # measured, depthless, measured
    pull = np.linalg.norm(OutsideTerm(outline, mask, K, np.ones(3, bool), measured).evaluate(V)[1], axis=1)
    assert pull[0] > 0 and pull[2] > 0 and pull[1] == 0
    assert np.linalg.norm(OutsideTerm(outline, mask, K, np.ones(3, bool)).evaluate(V)[1], axis=1)[1] > 0


def test_outside_leaves_the_vertices_nearest_a_hidden_stretch_of_the_contour():
    """Something nearer hides the square's right edge from y = -0.05 to 0.05 (a gripper holding
    the cloth there). A vertex just right of that stretch may lie behind what hides it; the
    outline's nearest point is an end of the gap, 5 cm along the edge, and pulling it there
    would drag it along the cloth's edge. With the hidden stretch known it is left alone; a
    vertex off a seen stretch of the edge is pulled as before."""
    outline, mask = outline_square(1.2)
    gap = (np.abs(outline[:, 0] - 0.1) < 1e-9) & (np.abs(outline[:, 1]) < 0.05)
    V = np.array([[0.12, 0.0, 1.2], [0.12, 0.02, 1.2], [0.13, -0.08, 1.2]])  # beside the gap; off a seen stretch
    seen = np.ones(3, bool)
    blind = np.linalg.norm(OutsideTerm(outline[~gap], mask, K, seen).evaluate(V)[1], axis=1)
    assert blind.min() > 0
    term = OutsideTerm(outline[~gap], mask, K, seen, hidden_points=outline[gap])
    _, grad = term.evaluate(V)
    assert np.all(grad[:2] == 0) and grad[2, 0] > 0
    check_gradient(term, V)


def test_free_space_pulls_only_the_vertices_the_camera_sees_past():
    # the object (a square at 1.2 m) in front of a wall 3 m away on the right and a table
    # 1.25 m away on the left: a vertex left in the air in front of the wall cannot be there
    # (the camera sees the wall through it) and is pulled back; one just in front of the
    # table (which explains it within the margin), one on a pixel without depth and one on
    # the object are left alone
    outline, mask = outline_square(1.2)
    depth = np.full(mask.shape, 3.0)
    depth[:, :320] = 1.25
    depth[:180, :] = 0.0  # no depth above the square
    depth[mask] = 1.2
    V = np.array([[0.15, 0.013, 1.2],   # right of the square, the wall far behind: seen past
                  [-0.15, 0.0, 1.2],    # left of it, the table 5 cm behind
                  [0.15, -0.2, 1.2],    # above it, no depth there
                  [0.0, 0.0, 1.2]])     # on it
    seen = np.ones(4, bool)
    term = OutsideTerm(outline, mask, K, seen, depth_m=depth, free_space_m=0.08, name="free_space")
    pull = np.linalg.norm(term.evaluate(V)[1], axis=1)
    assert pull[0] > 0 and pull[1] == 0 and pull[2] == 0 and pull[3] == 0
    check_gradient(term, V)
    # without the free-space test the term pulls the first two alike
    both = np.linalg.norm(OutsideTerm(outline, mask, K, seen).evaluate(V)[1], axis=1)
    assert both[0] > 0 and both[1] > 0
    with pytest.raises(ValueError, match="free_space_m"):
        OutsideTerm(outline, mask, K, seen, free_space_m=0.08)


def test_match_gated_follows_the_papers_rules():
    from perception.features import Keypoints, match_gated

    rng = np.random.default_rng(0)
    desc = rng.normal(size=(6, 8)).astype(np.float32)
    model = Keypoints(np.zeros((6, 2), np.float32), desc, False)
    pred = np.array([[10, 10], [50, 50], [90, 90], [130, 130], [170, 170], [np.nan, np.nan]], float)
    # current features: exact copies near each prediction, plus a better descriptor out of the gate
    cur_xy = pred[:5] + 3.0
    cur_desc = desc[:5] + rng.normal(0, [[0.01], [0.02], [0.3], [0.4], [0.5]], (5, 8)).astype(np.float32)
    far = Keypoints(np.array([[10, 200]], np.float32), desc[:1].copy(), False)
    current = Keypoints(np.concatenate([cur_xy, far.xy]).astype(np.float32), np.concatenate([cur_desc, far.desc]), False)
    mi, ci = match_gated(model, pred, current, gate_px=20, keep_fraction=0.5)
    # five gated matches (the NaN prediction and the far copy never match), best half kept: 3
    assert sorted(mi.tolist()) == [0, 1, 2]
    np.testing.assert_array_equal(mi, ci)
