"""Scene data and set-up: the object catalog, scene-config validation and the placement sampler."""

from __future__ import annotations

import numpy as np
import pytest

from safemanip.env import margins as M
from safemanip.env.config import EnvConfigError
from safemanip.env.slide_out import SlideOutEnv
from safemanip.scene import config as config_module
from safemanip.scene.builder import build_model
from safemanip.scene.catalog import (CONSTRAINT_OF_CLASS, CONSTRAINT_TYPES, SEMANTIC_CLASSES, CatalogError, _parse,
                                     load_catalog, names_of_class)
from safemanip.scene.config import GEOMETRY, MAX_OBJECTS, SceneConfig, SceneConfigError, parse_semantics
from safemanip.scene.placement import (_CLEARANCE, LAYOUTS, ROUTE_BEND, PlacementError,
                                       sample_placement, sample_route)

CATALOG = load_catalog()
BOX_HALF = GEOMETRY.box_half_extents
ALL_RADII = np.array([CATALOG[n].footprint_radius for n in sorted(CATALOG)])

# ================================================================== catalog


def test_catalog_size_and_classes():
    assert len(CATALOG) >= 30
    counts = {c: len(names_of_class(c)) for c in SEMANTIC_CLASSES}
    # every class can fill a whole scene on its own ("8 fragile" must be a valid request)
    assert all(n >= MAX_OBJECTS for n in counts.values()), counts
    assert sum(counts.values()) == len(CATALOG)


def test_constraint_follows_class():
    assert CONSTRAINT_OF_CLASS == {"fragile": "no_contact", "soft": "soft_contact", "durable": "any_contact"}
    for obj in CATALOG.values():
        assert obj.constraint == CONSTRAINT_OF_CLASS[obj.semantic_class]
        assert obj.constraint in CONSTRAINT_TYPES


@pytest.mark.parametrize("name,semantic_class", [
    ("toy squirrel", "durable"), ("toy sheep", "durable"), ("toy android", "durable"),
    ("red mug", "fragile"), ("blue mug", "fragile"), ("porcelain mug", "fragile"),
    ("supplement bottle", "soft"),
])
def test_catalog_holds_the_papers_objects(name, semantic_class):
    assert CATALOG[name].semantic_class == semantic_class


def test_plant_pot_ground_truth_is_soft_as_in_the_paper():
    """Paper Tables III/IV: the 'no contact (GT)' row (99.0 / 1.0 / 0.0) is exactly the mean of the three
    mug rows of Table IV, and the 'any contact (GT)' row is the three toys; the text calls the supplement
    bottle and the plant pot "semi-fragile objects [that] are allowed soft contacts ... our ground truth".
    The VLM's 73 % 'no contact' for the plant pot is a *misprediction*, not the ground truth."""
    assert CATALOG["plant pot"].semantic_class == "soft"


def test_catalog_objects_are_sane():
    for name, obj in CATALOG.items():
        assert obj.name == name
        assert 0.01 <= obj.mass <= 2.0, name
        assert len(obj.rgba) == 4 and all(0.0 <= c <= 1.0 for c in obj.rgba), name
        assert 0.01 < obj.footprint_radius <= 0.12, name
        assert 0.005 < obj.height <= 0.25, name


def _support_xy(model, g, u):
    """max over the points of geom g (in its body frame) of p . u, for a horizontal unit vector u."""
    import mujoco

    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    rot = rot.reshape(3, 3)
    centre, size, kind = model.geom_pos[g], model.geom_size[g], model.geom_type[g]
    axis = rot[:, 2]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return centre @ u + np.abs(rot.T @ u) @ size
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return centre @ u + size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return centre @ u + abs(axis @ u) * size[1] + size[0]
    if kind == mujoco.mjtGeom.mjGEOM_CYLINDER:
        c = axis @ u
        return centre @ u + abs(c) * size[1] + size[0] * np.sqrt(max(0.0, 1 - c * c))
    raise AssertionError(f"unexpected geom type {kind}")


def test_footprint_radius_contains_the_compiled_geoms():
    """The placement sampler's no-overlap promise is only as good as the footprint circles."""
    names = sorted(CATALOG)
    angles = np.linspace(0, 2 * np.pi, 181)
    dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    for start in range(0, len(names), MAX_OBJECTS):
        chunk = tuple(names[start:start + MAX_OBJECTS])
        model = build_model(chunk, False)
        for i, name in enumerate(chunk):
            body = model.body(f"obj{i}").id
            reach = max(_support_xy(model, g, u) for g in np.flatnonzero(model.geom_bodyid == body) for u in dirs)
            fp = CATALOG[name].footprint_radius
            assert reach <= fp + 1e-6, f"{name}: geoms reach {reach:.4f} m > footprint {fp:.4f} m"
            assert fp <= reach + 0.03, f"{name}: footprint {fp:.4f} m is far too loose (geoms reach {reach:.4f} m)"


def test_objects_rest_on_their_base():
    """Catalog convention: z = 0 is where the object rests, so every object's lowest point is at z = 0."""
    names = sorted(CATALOG)
    down = np.array([0.0, 0.0, -1.0])
    import mujoco

    bad = {}
    for start in range(0, len(names), MAX_OBJECTS):
        chunk = tuple(names[start:start + MAX_OBJECTS])
        model = build_model(chunk, False)
        for i, name in enumerate(chunk):
            body = model.body(f"obj{i}").id
            lowest = np.inf
            for g in np.flatnonzero(model.geom_bodyid == body):
                rot = np.zeros(9)
                mujoco.mju_quat2Mat(rot, model.geom_quat[g])
                rot = rot.reshape(3, 3)
                size, kind, centre = model.geom_size[g], model.geom_type[g], model.geom_pos[g]
                if kind == mujoco.mjtGeom.mjGEOM_BOX:
                    low = centre[2] - np.abs(rot.T @ down) @ size
                elif kind == mujoco.mjtGeom.mjGEOM_SPHERE:
                    low = centre[2] - size[0]
                elif kind == mujoco.mjtGeom.mjGEOM_CAPSULE:
                    low = centre[2] - abs(rot[2, 2]) * size[1] - size[0]
                else:  # cylinder
                    c = rot[2, 2]
                    low = centre[2] - abs(c) * size[1] - size[0] * np.sqrt(max(0.0, 1 - c * c))
                lowest = min(lowest, low)
            if abs(lowest) > 1e-3:
                bad[name] = round(float(lowest), 4)
    assert not bad, f"objects whose lowest point is not at z = 0 (they drop or start sunk into the table): {bad}"


def test_catalog_parser_rejects_bad_entries():
    good = {"name": "x", "class": "fragile", "mass": 0.1, "rgba": [1, 0, 0, 1],
            "parts": [{"type": "sphere", "size": [0.03], "pos": [0, 0, 0.03]}]}
    assert list(_parse({"objects": [good]})) == ["x"]
    with pytest.raises(CatalogError, match="class must be one of"):
        _parse({"objects": [{**good, "class": "squishy"}]})
    with pytest.raises(CatalogError, match="that many sizes"):
        _parse({"objects": [{**good, "parts": [{"type": "box", "size": [0.1, 0.1], "pos": [0, 0, 0]}]}]})
    with pytest.raises(CatalogError, match="that many sizes"):
        _parse({"objects": [{**good, "parts": [{"type": "torus", "size": [0.1], "pos": [0, 0, 0]}]}]})
    with pytest.raises(CatalogError, match="duplicate name"):
        _parse({"objects": [good, good]})


# ================================================================== config


def test_parse_semantics():
    assert parse_semantics("2 fragile, 3 durable") == ("fragile",) * 2 + ("durable",) * 3
    assert parse_semantics("2 fragile, 2 soft, 1 durable") == ("fragile", "fragile", "soft", "soft", "durable")
    assert parse_semantics(" 1 soft ,") == ("soft",)


@pytest.mark.parametrize("text", ["two fragile", "2 fragil", "2 fragile; 3 durable", "fragile", "2 Fragile x"])
def test_parse_semantics_rejects_bad_strings(text):
    with pytest.raises(SceneConfigError, match="cannot read .* write e.g."):
        parse_semantics(text)


def test_scene_config_defaults_and_valid_requests():
    assert SceneConfig().n_objects == 4
    assert SceneConfig(n_objects=0).n_objects == 0
    assert SceneConfig(n_objects=MAX_OBJECTS).n_objects == MAX_OBJECTS
    cfg = SceneConfig(n_objects=2, names=["red mug", "toy sheep"])
    assert cfg.names == ("red mug", "toy sheep")  # normalised to a tuple
    cfg = SceneConfig(n_objects=5, classes=parse_semantics("2 fragile, 3 durable"))
    assert cfg.classes.count("durable") == 3
    SceneConfig(n_objects=8, classes=("fragile",) * 8)


@pytest.mark.parametrize("n", [9, -1, 2.0, "3", None])
def test_n_objects_out_of_range(n):
    with pytest.raises(SceneConfigError, match="n_objects must be an integer from 0 to 8"):
        SceneConfig(n_objects=n)


def test_unknown_names():
    with pytest.raises(SceneConfigError, match=r"unknown object name\(s\) \['unicorn'\]"):
        SceneConfig(n_objects=2, names=("red mug", "unicorn"))


def test_wrong_name_count():
    with pytest.raises(SceneConfigError, match="2 names given for n_objects=3"):
        SceneConfig(n_objects=3, names=("red mug", "toy sheep"))


def test_duplicate_names():
    with pytest.raises(SceneConfigError, match="distinct"):
        SceneConfig(n_objects=2, names=("red mug", "red mug"))


def test_unknown_and_miscounted_classes():
    with pytest.raises(SceneConfigError, match=r"unknown class\(es\) \['squishy'\]"):
        SceneConfig(n_objects=2, classes=("fragile", "squishy"))
    with pytest.raises(SceneConfigError, match="3 classes given for n_objects=2"):
        SceneConfig(n_objects=2, classes=("fragile", "soft", "durable"))


def test_too_many_of_a_class(monkeypatch):
    small = {n: CATALOG[n] for n in ("red mug", "blue mug", "soda can", "toy sheep")}
    monkeypatch.setattr(config_module, "load_catalog", lambda: small)
    with pytest.raises(SceneConfigError, match="asked for 3 fragile objects but the catalog has only 2"):
        SceneConfig(n_objects=3, classes=("fragile",) * 3)
    SceneConfig(n_objects=2, classes=("fragile",) * 2)  # exactly what there is: fine


@pytest.mark.parametrize("fraction", [-0.1, 1.5])
def test_near_path_fraction_range(fraction):
    with pytest.raises(SceneConfigError, match="near_path_fraction"):
        SceneConfig(near_path_fraction=fraction)


def test_config_errors_are_value_errors():
    assert issubclass(SceneConfigError, ValueError)
    assert issubclass(PlacementError, SceneConfigError)


# ================================================================== placement

START = np.asarray(GEOMETRY.path_start_xy)
GOAL = np.asarray(GEOMETRY.goal_xy)


def _rect_gap(xy, r, centre, half):
    """Distance from a circle's edge to an axis-aligned rectangle (negative if they overlap)."""
    d = np.maximum(np.abs(np.asarray(xy) - centre) - half, 0.0)
    return float(np.hypot(*d)) - r


def _footprints_to_avoid():
    hx, hy, _ = GEOMETRY.box_half_extents
    half = np.array([hx, hy])
    return {"top box": (np.asarray(GEOMETRY.stack_xy), half), "bottom box": (np.asarray(GEOMETRY.bottom_xy), half),
            "pulled-out box": (START, half)}


def _check_placement(p, radii):
    n = len(radii)
    assert p.xy.shape == (n, 2) and p.yaw.shape == (n,) and p.near_path.shape == (n,)
    assert np.all(np.abs(p.yaw) <= np.pi)
    tx, ty = GEOMETRY.table_half_extents
    for i in range(n):
        x, y = p.xy[i]
        r = radii[i]
        assert abs(x) + r <= tx and abs(y) + r <= ty, f"object {i} hangs over the table edge"
        for j in range(i):
            gap = np.hypot(*(p.xy[i] - p.xy[j])) - radii[i] - radii[j]
            assert gap >= _CLEARANCE - 1e-9, f"objects {i} and {j} overlap (gap {gap:.4f} m)"
        for what, (centre, half) in _footprints_to_avoid().items():
            assert _rect_gap(p.xy[i], r, centre, half) >= _CLEARANCE, f"object {i} is on the {what}"
        assert np.hypot(*(p.xy[i] - GOAL)) >= GEOMETRY.goal_radius + r, f"object {i} is in the goal region"


def test_placement_never_overlaps_over_many_seeds():
    for seed in range(150):
        rng = np.random.default_rng(seed)
        for n in range(MAX_OBJECTS + 1):
            radii = rng.choice(ALL_RADII, size=n, replace=False)
            p = sample_placement(radii, np.random.default_rng(1000 * seed + n), 0.5)
            _check_placement(p, radii)


@pytest.mark.parametrize("fraction", [0.0, 1.0])
def test_placement_with_the_largest_objects(fraction):
    # all 8 largest anywhere; the 4 largest (radius ~0.1 m) all inside the near-path corridor
    radii = np.sort(ALL_RADII)[-MAX_OBJECTS:] if fraction == 0.0 else np.sort(ALL_RADII)[-4:]
    for seed in range(20):
        p = sample_placement(radii, np.random.default_rng(seed), fraction)
        _check_placement(p, radii)


def test_placement_is_deterministic_for_a_seed():
    radii = ALL_RADII[:6]
    a = sample_placement(radii, np.random.default_rng(7), 0.5)
    b = sample_placement(radii, np.random.default_rng(7), 0.5)
    c = sample_placement(radii, np.random.default_rng(8), 0.5)
    assert np.array_equal(a.xy, b.xy) and np.array_equal(a.yaw, b.yaw) and np.array_equal(a.near_path, b.near_path)
    assert not np.allclose(a.xy, c.xy)


def test_empty_placement():
    p = sample_placement(np.zeros(0), np.random.default_rng(0), 0.5)
    assert p.xy.shape == (0, 2) and p.yaw.shape == (0,) and p.near_path.shape == (0,)


def _path_coordinates(xy):
    """(fraction along the start->goal segment, signed distance from its line) of each point."""
    direction = GOAL - START
    length = np.linalg.norm(direction)
    rel = np.asarray(xy) - START
    along = rel @ direction / length ** 2
    normal = np.array([-direction[1], direction[0]]) / length
    return along, rel @ normal


@pytest.mark.parametrize("fraction,n", [(0.5, 4), (1.0, 5), (0.25, 8), (0.0, 6)])
def test_near_path_fraction_puts_objects_near_the_path(fraction, n):
    rng = np.random.default_rng(3)
    all_dist_near, full_corridor = [], 0
    for seed in range(30):
        radii = rng.choice(ALL_RADII, size=n, replace=False)
        p = sample_placement(radii, np.random.default_rng(seed), fraction)
        # as many as asked for, unless the corridor is full (then the rest go anywhere free)
        assert p.near_path.sum() <= int(round(fraction * n))
        full_corridor += p.near_path.sum() < int(round(fraction * n))
        along, across = _path_coordinates(p.xy[p.near_path])
        assert np.all((along >= 0.05 - 1e-9) & (along <= 0.95 + 1e-9)), along
        assert np.all(np.abs(across) <= 0.30 + 1e-9), across
        all_dist_near += np.abs(across).tolist()
    assert full_corridor <= 3  # of 30 scenes
    if fraction > 0:
        # the narrow (0.14 m) corridor is the rule, the widened one the exception
        assert np.mean(np.asarray(all_dist_near) <= 0.14 + 1e-9) > 0.7


def test_near_path_objects_are_closer_to_the_path_than_the_rest():
    radii = np.full(8, 0.04)
    near_d, far_d = [], []
    for seed in range(30):
        p = sample_placement(radii, np.random.default_rng(seed), 0.5)
        _, across = _path_coordinates(p.xy)
        near_d += np.abs(across[p.near_path]).tolist()
        far_d += np.abs(across[~p.near_path]).tolist()
    assert np.mean(near_d) < 0.1 < np.mean(far_d)


def test_placement_that_cannot_fit_raises_a_helpful_error():
    with pytest.raises(PlacementError) as err:
        sample_placement(np.full(8, 0.3), np.random.default_rng(0), 0.0, max_tries=200)
    msg = str(err.value)
    assert "could not place 8 objects" in msg and "reduce n_objects" in msg and "smaller objects" in msg
    # a full corridor is no error: the objects that do not fit there go anywhere free
    p = sample_placement(np.full(5, 0.1), np.random.default_rng(0), 1.0, max_tries=200)
    assert 0 < p.near_path.sum() < 5


def _model_bytes(model) -> bytes:
    import mujoco

    buf = np.zeros(mujoco.mj_sizeModel(model), np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return buf.tobytes()


@pytest.mark.parametrize("embodiment", ["panda", "hand"])
def test_scenes_built_from_the_cached_base_equal_scenes_built_from_scratch(embodiment):
    """The table, robot and boxes are built once and copied for every object set: the copy must not carry
    anything from an earlier scene, and must compile to the same bytes as a scene built from nothing."""
    from safemanip.scene import builder
    from safemanip.scene.embodiment import make_embodiment

    robot = make_embodiment(embodiment, visual=False, gap=0.01)
    builder.build_spec(("camera", "tennis ball", "wine glass"), robot).compile()  # leaves the base cached
    names = ("red mug", "toy squirrel")
    cached = builder.build_spec(names, robot).compile()
    builder._BASES.clear()
    scratch = builder.build_spec(names, robot).compile()
    assert _model_bytes(cached) == _model_bytes(scratch)


def _placement_one_try_at_a_time(radii, rng, near_path_fraction, max_tries=1000):
    """The sampler's rule drawn one try at a time (how it was written before it drew tries in batches)."""
    from safemanip.scene.placement import _free, _keep_out_rects

    n = len(radii)
    n_near = int(round(near_path_fraction * n))
    sx, sy = (float(v) for v in GEOMETRY.path_start_xy)
    dx, dy = GEOMETRY.goal_xy[0] - sx, GEOMETRY.goal_xy[1] - sy
    length = np.sqrt(dx * dx + dy * dy)
    nx, ny = -dy / length, dx / length
    tx, ty = GEOMETRY.table_half_extents
    placed, xy, near = [], np.zeros((n, 2)), np.zeros(n, dtype=bool)
    for rank, i in enumerate(np.argsort(-np.asarray(radii), kind="stable").tolist()):
        want_near, r = rank < n_near, float(radii[i])
        for attempt in range(2 * max_tries if want_near else max_tries):
            near_try = want_near and attempt < max_tries
            if near_try:
                width = 0.14 if attempt < max_tries // 4 else 0.30
                along, across = rng.uniform(0.05, 0.95), rng.uniform(-width, width)
                x, y = sx + along * dx + across * nx, sy + along * dy + across * ny
            else:
                x, y = rng.uniform(-tx, tx), rng.uniform(-ty, ty)
            if _free(x, y, r, placed, GEOMETRY, _keep_out_rects(GEOMETRY)):
                break
        placed.append((x, y, r))
        xy[i], near[i] = (x, y), near_try
    return xy, rng.uniform(-np.pi, np.pi, size=n), near


def test_batched_placement_equals_drawing_one_try_at_a_time():
    """The sampler draws its tries in batches for speed; it must give bit for bit the placements, and leave
    the generator in the state, of drawing one try at a time (so a seed's scene never changes), also when
    the corridor is crowded and objects fall back to the rest of the table."""
    crowded = 0
    for seed in range(300):
        pick = np.random.default_rng(seed)
        n = int(pick.integers(1, MAX_OBJECTS + 1))
        radii = pick.choice(ALL_RADII if seed % 3 else np.sort(ALL_RADII)[-MAX_OBJECTS:], size=n, replace=False)
        fraction = (0.0, 0.5, 1.0)[seed % 3]
        a, b = np.random.default_rng(seed + 10_000), np.random.default_rng(seed + 10_000)
        p = sample_placement(radii, a, fraction)
        xy, yaw, near = _placement_one_try_at_a_time(radii, b, fraction)
        assert np.array_equal(p.xy, xy) and np.array_equal(p.yaw, yaw) and np.array_equal(p.near_path, near), seed
        assert a.bit_generator.state == b.bit_generator.state, seed
        crowded += int(fraction == 1.0 and not near.all())
    assert crowded > 0  # the fall-back path was exercised


# ================================================================== route layout (the default)


def _band_gap(xy, r, route):
    """Distance from a footprint circle's edge to the route's kept-clear band (negative if they overlap)."""
    hx, hy = route.half_extents
    d = np.maximum(np.abs(np.asarray(xy)[None, :] - route.points) - np.array([hx, hy]), 0.0)
    return float(np.hypot(d[:, 0], d[:, 1]).min()) - r


def test_a_route_runs_from_the_lane_to_the_goal_with_a_bend_in_range():
    far_neg, near_neg, near_pos, far_pos = ROUTE_BEND
    bends = []
    for seed in range(200):
        route = sample_route(np.random.default_rng(seed))
        assert np.allclose(route.points[0], START) and np.allclose(route.points[-1], GOAL)
        assert np.linalg.norm(np.diff(route.points, axis=0), axis=1).max() <= 0.02 + 1e-9
        assert far_neg <= route.bend <= near_neg or near_pos <= route.bend <= far_pos, route.bend
        bends.append(route.bend)
    assert 0.3 < np.mean(np.asarray(bends) > 0) < 0.7  # both sides


@pytest.mark.parametrize("name", list(LAYOUTS))
def test_route_layouts_keep_the_band_clear_and_put_near_objects_beside_it(name):
    layout = LAYOUTS[name]
    rng = np.random.default_rng(5)
    gaps, inner = [], []
    for seed in range(150):
        n = int(rng.integers(1, MAX_OBJECTS + 1))
        radii = rng.choice(ALL_RADII, size=n, replace=False)
        draw = np.random.default_rng(seed)
        route = sample_route(draw, layout=layout)
        p = sample_placement(radii, draw, layout.near_fraction, route=route)
        _check_placement(p, radii)
        assert p.route is route
        # the band is the held box and hand plus the layout's clearance
        assert np.isclose(route.half_extents[1], BOX_HALF[1] + layout.clearance)
        for i in range(n):
            gap = _band_gap(p.xy[i], radii[i], route)
            assert gap >= _CLEARANCE - 1e-9, f"seed {seed}: object {i} stands on the route ({gap:.4f} m)"
            if p.near_path[i]:
                assert gap <= _CLEARANCE + 0.30 + 1e-6, f"seed {seed}: near-path object {i} is {gap:.3f} m away"
                if n <= 4:  # more objects crowd the close band and spill into the wider one
                    gaps.append(gap)
                # inside the bend = on the side of the nearest route segment away from the bend
                j = min(int(np.argmin(np.linalg.norm(route.points - p.xy[i], axis=1))), len(route.points) - 2)
                step = route.points[j + 1] - route.points[j]
                side = np.sign((p.xy[i] - route.points[j]) @ np.array([-step[1], step[0]]))
                inner.append(side != np.sign(route.bend))
    assert np.mean(np.asarray(gaps) <= _CLEARANCE + layout.near_gap + 1e-6) > 0.8  # the close band is the rule
    # inner_share of the tries go inside the bend; the stack's keep-out rejects some of them near the lane
    assert layout.inner_share - 0.4 < np.mean(inner) <= layout.inner_share + 0.05, np.mean(inner)


def test_the_narrow_layout_is_a_channel():
    """Against the default: a band with d4 (1 cm) to spare instead of 2 cm, every object beside it (as many as
    fit), on both sides of the bend, and closer to it."""
    route, narrow = LAYOUTS["route"], LAYOUTS["narrow"]
    assert narrow.clearance < route.clearance and narrow.clearance >= M.DEFAULT_THRESHOLDS.collision  # d4
    assert narrow.near_gap < route.near_gap and narrow.near_fraction == 1.0
    assert 0.3 <= narrow.inner_share <= 0.7  # both sides, not mostly inside the bend
    env = SlideOutEnv(n_objects=4, classes="4 fragile", constraints="conservative", layout="narrow")
    for seed in range(10):
        env.reset(seed=seed)
        assert env.placement.near_path.all() and env.placement.route.layout is narrow
    with pytest.raises(EnvConfigError, match="keeps a route clear"):
        SlideOutEnv(n_objects=2, layout="narrow", clear_route=False)
    with pytest.raises(EnvConfigError, match="layout must be one of route, narrow"):
        SlideOutEnv(n_objects=2, layout="tight")


def test_route_layout_is_deterministic_for_a_seed():
    radii = ALL_RADII[:6]
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    pa, pb = sample_placement(radii, a, 0.5, route=sample_route(a)), sample_placement(radii, b, 0.5, route=sample_route(b))
    assert np.array_equal(pa.xy, pb.xy) and np.array_equal(pa.route.points, pb.route.points)
    assert a.bit_generator.state == b.bit_generator.state
