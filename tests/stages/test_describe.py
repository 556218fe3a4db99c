"""Tests of the describe stage on synthetic scenes with known geometry.

The scenes are vertical plates (fronto-parallel rectangles standing on flat ground) seen by a
camera of known height and pitch, ray-traced exactly: every descriptor has a known answer.
"""

from __future__ import annotations

import math

import duckdb
import numpy as np
import pyarrow as pa
import pytest

from pipeline.camera import Camera
from pipeline.stage import FrameContext
from stages.describe import DESCRIPTOR_SCHEMA, RELATION_SCHEMA, STAGE, describe_frame

CAMERA = Camera(focal_px=200.0, baseline_m=0.2, height_m=1.0, pitch_deg=35.0)
SHAPE = (120, 160)


def plate_scene(camera: Camera, shape: tuple[int, int], plates: list[tuple], ground_gray=100):
    """Ray-trace vertical plates ``(x0, y0, width, height, gray)`` (ground frame) on flat ground.

    Returns labels, gray, disparity, range (camera Z) and height above ground, reference
    geometry; plate k gets label k.
    """
    cx, cy = camera.principal_point(shape)
    f, h = camera.focal_px, camera.height_m
    th = math.radians(camera.pitch_deg)
    v, u = np.indices(shape, dtype=np.float64)
    u, v = (u - cx) / f, (v - cy) / f
    # ray (u, v, 1) in the ground frame; its parameter is the camera depth Z
    dx, dy, dz = u, math.cos(th) - v * math.sin(th), -(v * math.cos(th) + math.sin(th))
    depth = np.where(dz < 0, h / np.where(dz < 0, -dz, 1.0), np.inf)
    labels = np.zeros(shape, np.int32)
    height = np.zeros(shape)
    gray = np.full(shape, float(ground_gray))
    for k, (x0, y0, width, plate_h, plate_gray) in enumerate(plates, start=1):
        t = y0 / dy
        z, x = h + t * dz, t * dx
        hit = (t > 0) & (z >= 0) & (z <= plate_h) & (np.abs(x - x0) <= width / 2) & (t < depth)
        depth = np.where(hit, t, depth)
        labels[hit], height[hit], gray[hit] = k, z[hit], plate_gray
    valid = np.isfinite(depth)
    disparity = np.where(valid, camera.k_m_px / np.where(valid, depth, 1.0), np.nan)
    rng = np.where(valid, depth, np.nan)
    height[~valid] = np.nan
    return (
        labels,
        gray.astype(np.uint8),
        disparity.astype(np.float32),
        rng.astype(np.float32),
        height.astype(np.float32),
    )


def _run(plates, camera=CAMERA, **kwargs):
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, plates)
    return describe_frame(labels, gray, disparity, rng, height, camera=camera, **kwargs), (
        labels,
        rng,
    )


def _row(desc, object_id):
    index = int(np.flatnonzero(desc["object_id"] == object_id)[0])
    return {name: values[index] for name, values in desc.items()}


def test_single_plate_metric_fields():
    x0, y0, width, plate_h = -0.15, 1.6, 0.20, 0.12
    (desc, rel, figures), (labels, rng) = _run([(x0, y0, width, plate_h, 60)])
    row = _row(desc, 1)
    z = float(np.median(rng[labels == 1]))
    pixel_m = z / CAMERA.focal_px
    assert row["range_m"] == pytest.approx(z, rel=1e-6)
    assert row["range_err_m"] == pytest.approx(z**2 / CAMERA.k_m_px * 0.5, rel=1e-6)
    assert row["width_m"] == pytest.approx(width, abs=1.5 * pixel_m)
    assert row["height_m"] == pytest.approx(plate_h, abs=1.5 * pixel_m)
    assert row["height_max_m"] == pytest.approx(plate_h, abs=1.5 * pixel_m)
    assert row["height_m"] <= row["height_max_m"] + 1e-9
    assert row["x_m"] == pytest.approx(x0, abs=pixel_m)
    assert row["y_m"] == pytest.approx(y0, abs=1e-6)
    assert row["z_m"] == pytest.approx(0.0, abs=1e-6)
    # width: the plate's largest horizontal dimension; length across it: one pixel (a plate)
    assert row["length_m"] == pytest.approx(pixel_m, rel=0.05)
    assert 0 < row["height_err_m"] < row["range_err_m"]
    assert 0 < row["width_err_m"] < 0.05
    assert row["depth_valid_fraction"] == 1.0
    assert not row["depth_unreliable"] and not row["occluded"] and not row["touches_border"]
    assert row["size_class"] == "obstacle"
    assert row["polarity"] == "darker"
    assert rel["subject_id"].size == 0
    assert figures["rock_count"] == 1 and figures["n_obstacles"] == 1
    assert figures["ground_source"] == "camera"


def test_small_plate_is_a_sample_and_classes_follow_params():
    (desc, _, figures), _ = _run([(0.1, 1.5, 0.06, 0.04, 200)])
    assert _row(desc, 1)["size_class"] == "sample"
    assert figures["n_samples"] == 1 and figures["n_obstacles"] == 0
    (desc, _, _), _ = _run([(0.1, 1.5, 0.06, 0.04, 200)], rover_clearance_m=0.02)
    assert _row(desc, 1)["size_class"] == "obstacle"
    (desc, _, _), _ = _run([(0.1, 1.5, 0.06, 0.04, 200)], sample_max_m=0.03)
    assert _row(desc, 1)["size_class"] == "obstacle"


def test_plane_fit_frame_agrees_with_camera_pose():
    theta = math.radians(CAMERA.pitch_deg)
    plane = np.array([0.0, -math.cos(theta), -math.sin(theta), CAMERA.height_m])
    no_pose = Camera(focal_px=CAMERA.focal_px, baseline_m=CAMERA.baseline_m)
    plates = [(-0.2, 1.5, 0.15, 0.1, 60), (0.25, 2.0, 0.2, 0.2, 180)]
    (with_pose, rel_pose, fig_pose), _ = _run(plates)
    (with_plane, rel_plane, fig_plane), _ = _run(plates, camera=no_pose, ground_plane=plane)
    for name in ("x_m", "y_m", "z_m", "width_m", "height_m", "height_err_m"):
        np.testing.assert_allclose(with_plane[name], with_pose[name], atol=1e-9)
    np.testing.assert_array_equal(rel_plane["relation"], rel_pose["relation"])
    assert fig_plane["ground_source"] == "plane"
    assert fig_plane["ground_area_m2"] == pytest.approx(fig_pose["ground_area_m2"])


def test_without_pose_or_plane_positions_are_unknown():
    no_pose = Camera(focal_px=CAMERA.focal_px, baseline_m=CAMERA.baseline_m)
    plates = [(-0.2, 1.5, 0.15, 0.1, 60), (0.25, 2.0, 0.2, 0.2, 180)]
    (desc, rel, figures), _ = _run(plates, camera=no_pose, ground_plane=np.full(4, np.nan))
    assert np.isnan(desc["x_m"]).all() and np.isnan(desc["y_m"]).all()
    assert np.isfinite(desc["range_m"]).all() and np.isfinite(desc["width_m"]).all()
    assert np.isfinite(desc["height_m"]).all()  # from the height map
    assert not set(rel["relation"]) & {"left_of", "right_of", "in_front_of", "behind"}
    assert figures["ground_source"] == "none" and math.isnan(figures["sfd_k"])


def test_relations_of_an_occluding_pair_and_a_sample_behind():
    plates = [
        (-0.25, 1.6, 0.2, 0.3, 60),  # 1: obstacle in front
        (-0.25, 1.75, 0.5, 0.4, 150),  # 2: wide obstacle just behind 1, partly hidden by it
        (0.3, 2.2, 0.06, 0.05, 220),  # 3: sample far right and behind
    ]
    (desc, rel, figures), _ = _run(plates)
    edges = set(
        zip(
            rel["subject_id"].tolist(),
            rel["relation"].tolist(),
            rel["object_id"].tolist(),
            strict=True,
        )
    )
    assert (1, "occludes", 2) in edges and (2, "occludes", 1) not in edges
    assert {(1, "adjacent", 2), (2, "adjacent", 1)} <= edges
    assert {(1, "in_front_of", 2), (2, "behind", 1)} <= edges
    assert {(3, "behind", 1), (1, "in_front_of", 3), (3, "right_of", 1), (1, "left_of", 3)} <= edges
    assert not any(s == 3 and r in ("adjacent", "occludes") for s, r, _ in edges)
    # 1 and 2 are centred on the same x: a near-tie, no left/right edge
    assert not any({s, o} == {1, 2} and r in ("left_of", "right_of") for s, r, o in edges)
    occluded = dict(zip(desc["object_id"].tolist(), desc["occluded"].tolist(), strict=True))
    assert occluded == {1: False, 2: True, 3: False}
    behind = (rel["subject_id"] == 2) & (rel["relation"] == "behind") & (rel["object_id"] == 1)
    assert rel["overlap"][behind][0] == pytest.approx(1.0)
    assert rel["distance_m"][behind][0] == pytest.approx(0.15, abs=0.03)
    assert figures["n_relations"] == len(edges)


def test_sql_samples_behind_an_obstacle():
    plates = [
        (0.0, 1.5, 0.3, 0.25, 60),  # 1: obstacle
        (0.02, 2.0, 0.06, 0.05, 220),  # 2: sample behind it, in line of sight
        (0.5, 1.3, 0.05, 0.04, 220),  # 3: sample in front, off to the right
    ]
    (desc, rel, _), _ = _run(plates)
    frame = {"archive": "t", "run_id": "r", "frame_id": "f0"}
    descriptors = pa.table({**{k: [v] * desc["object_id"].size for k, v in frame.items()}, **desc})
    relations = pa.table({**{k: [v] * rel["subject_id"].size for k, v in frame.items()}, **rel})
    con = duckdb.connect()
    con.register("descriptors", descriptors)
    con.register("relations", relations)
    query = """
        SELECT s.frame_id, s.object_id AS sample_id, o.object_id AS obstacle_id
        FROM descriptors s
        JOIN relations r ON r.run_id = s.run_id AND r.frame_id = s.frame_id
                        AND r.subject_id = s.object_id AND r.relation = 'behind'
        JOIN descriptors o ON o.run_id = r.run_id AND o.frame_id = r.frame_id
                          AND o.object_id = r.object_id
        WHERE s.size_class = 'sample' AND o.size_class = 'obstacle' AND r.overlap > 0
    """
    assert con.execute(query).fetchall() == [("f0", 2, 1)]


def test_shadow_segmented_with_a_rock_does_not_widen_it():
    # regression: a sun shadow segmented with the rock (dark like it, but on the ground)
    # counted in the footprint; on runs/eval mojave the median width error was 11.3 %
    x0, y0, width = 0.0, 1.6, 0.20
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [(x0, y0, width, 0.1, 60)])
    cx, cy = CAMERA.principal_point(SHAPE)
    v, u = np.indices(SHAPE, dtype=np.float64)
    ground_x = (u - cx) / CAMERA.focal_px * rng  # camera X = ground x
    rows = np.nonzero((labels == 1).any(axis=1))[0]
    beside = (ground_x > x0 + width / 2) & (ground_x < x0 + width / 2 + 0.1)
    shadow = beside & (labels == 0) & (v >= rows.min()) & (v <= rows.max())
    labels[shadow] = 1  # 0.1 m of ground-level shadow to the right of the plate
    kwargs = {"camera": CAMERA}
    trimmed, _, _ = describe_frame(labels, gray, disparity, rng, height, **kwargs)
    whole, _, _ = describe_frame(labels, gray, disparity, rng, height, fringe_height_m=0, **kwargs)
    pixel_m = float(np.median(rng[labels == 1])) / CAMERA.focal_px
    # the shadow's 3 px next to the plate stay (a rock's own low rim would lie there)
    assert _row(trimmed, 1)["width_m"] == pytest.approx(width, abs=4.5 * pixel_m)
    assert _row(whole, 1)["width_m"] > width + 0.08
    for name in ("x_m", "y_m", "height_m", "range_m"):  # only the footprint changes
        assert _row(trimmed, 1)[name] == _row(whole, 1)[name]


def test_fringe_trimming_never_leaves_only_depthless_pixels():
    # the raised part has no depth (unknown heights are kept), the ground-level part has:
    # trimming the latter would leave no pixel to measure, so nothing is trimmed
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [(0.0, 1.6, 0.2, 0.1, 60)])
    plate = labels == 1
    rows = np.nonzero(plate.any(axis=1))[0]
    cols = np.nonzero(plate.any(axis=0))[0]
    strip = np.zeros(SHAPE, dtype=bool)
    strip[rows.min() : rows.max() + 1, cols.max() + 1 : cols.max() + 6] = True
    labels[strip & (labels == 0)] = 1  # ground-level pixels with depth beside the plate
    for arr in (disparity, rng, height):
        arr[plate] = np.nan
    desc, _, _ = describe_frame(
        labels, gray, disparity, rng, height, camera=CAMERA, fringe_reach_px=0
    )
    assert np.isfinite(_row(desc, 1)["width_m"])


def test_partly_invalid_depth_marks_unreliable():
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [(0.0, 1.6, 0.3, 0.2, 60)])
    mask = labels == 1
    rows = np.nonzero(mask)[0]
    lost = mask & (np.arange(SHAPE[0])[:, None] > np.percentile(rows, 30))
    for arr in (disparity, rng, height):
        arr[lost] = np.nan
    desc, _, _ = describe_frame(labels, gray, disparity, rng, height, camera=CAMERA)
    row = _row(desc, 1)
    assert row["depth_valid_fraction"] == pytest.approx(1 - lost.sum() / mask.sum())
    assert row["depth_unreliable"]
    desc, _, _ = describe_frame(
        labels, gray, disparity, rng, height, camera=CAMERA, min_valid_fraction=0.2
    )
    assert not _row(desc, 1)["depth_unreliable"]


def test_heights_fall_back_to_ground_frame_without_height_map():
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [(0.0, 1.6, 0.3, 0.2, 60)])
    with_map, _, _ = describe_frame(labels, gray, disparity, rng, height, camera=CAMERA)
    nan = np.full(SHAPE, np.nan, dtype=np.float32)
    without, _, _ = describe_frame(labels, gray, disparity, rng, nan, camera=CAMERA)
    for name in ("height_m", "height_max_m", "z_m"):
        np.testing.assert_allclose(without[name], with_map[name], atol=1e-5)


def test_empty_labels_give_typed_empty_tables():
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [])
    desc, rel, figures = describe_frame(labels, gray, disparity, rng, height, camera=CAMERA)
    for columns, schema in ((desc, DESCRIPTOR_SCHEMA), (rel, RELATION_SCHEMA)):
        assert list(columns) == schema.names
        table = pa.table(columns, schema=schema)
        assert table.num_rows == 0 and table.schema == schema
    assert figures["rock_count"] == 0 and figures["rock_area_fraction"] == 0.0


def test_tables_match_the_schemas():
    (desc, rel, _), _ = _run([(-0.2, 1.5, 0.15, 0.1, 60), (0.25, 2.0, 0.2, 0.2, 180)])
    for columns, schema in ((desc, DESCRIPTOR_SCHEMA), (rel, RELATION_SCHEMA)):
        assert list(columns) == schema.names
        assert pa.table(columns).schema == schema  # inferred types are the declared ones
        assert len({len(v) for v in columns.values()}) == 1


def test_size_frequency_figures():
    plates = [
        (x, 1.3 + 0.1 * i, 0.1 + 0.03 * i, 0.08, 60) for i, x in enumerate((-0.6, -0.2, 0.2, 0.6))
    ]
    (desc, _, figures), _ = _run(plates)
    assert figures["ground_area_m2"] > 0
    expected = np.sum(math.pi * desc["width_m"] ** 2 / 4) / figures["ground_area_m2"]
    assert figures["rock_area_fraction"] == pytest.approx(expected)
    assert 0 < figures["sfd_k"] < 1
    assert figures["sfd_q"] == pytest.approx(1.79 + 0.152 / figures["sfd_k"])
    (_, _, near_only), _ = _run(plates, sfd_max_range_m=0.5)
    assert near_only["sfd_n_rocks"] == 0 and math.isnan(near_only["sfd_k"])


def test_stage_declaration_and_run():
    assert STAGE.name == "describe" and STAGE.version == "11"
    assert STAGE.inputs == (
        "left", "right", "labels", "disparity", "range", "height", "ground_plane"
    )
    assert [(p.name, p.kind, p.schema) for p in STAGE.outputs] == [
        ("descriptors", "table", DESCRIPTOR_SCHEMA),
        ("relations", "table", RELATION_SCHEMA),
    ]
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [(0.0, 1.6, 0.3, 0.2, 60)])
    inputs = {
        "right": gray,
        "labels": labels,
        "disparity": disparity,
        "range": rng,
        "height": height,
        "ground_plane": np.full(4, np.nan),
    }
    frame = FrameContext(frame_id="f0", archive="t", camera=CAMERA)
    result = STAGE.run(inputs, frame=frame, params=STAGE.resolve_params({"margin_m": 0.1}))
    assert set(result.tables) == {"descriptors", "relations"}
    assert result.tables["descriptors"]["object_id"].tolist() == [1]
    assert result.figures["rock_count"] == 1


def test_bad_ground_plane_shape_is_rejected():
    labels, gray, disparity, rng, height = plate_scene(CAMERA, SHAPE, [])
    with pytest.raises(ValueError, match="4 coefficients"):
        describe_frame(labels, gray, disparity, rng, height, camera=CAMERA, ground_plane=[1, 2])


def test_object_without_depth_stands_on_the_ground_plane():
    x0, y0, width, plate_h = 0.1, 1.7, 0.25, 0.12
    labels, gray, disparity, rng, height = plate_scene(
        CAMERA, SHAPE, [(x0, y0, width, plate_h, 60)]
    )
    mask = labels == 1
    z_base = float(rng[mask].max())
    for arr in (disparity, rng, height):
        arr[mask] = np.nan
    desc, _, _ = describe_frame(labels, gray, disparity, rng, height, camera=CAMERA)
    row = _row(desc, 1)
    pixel_m = z_base / CAMERA.focal_px
    assert row["depth_valid_fraction"] == 0.0 and row["depth_unreliable"]
    assert row["range_m"] == pytest.approx(z_base, rel=0.02)
    assert math.isnan(row["range_err_m"])
    assert row["y_m"] == pytest.approx(y0, abs=0.02)
    assert row["x_m"] == pytest.approx(x0, abs=2 * pixel_m)
    assert row["width_m"] == pytest.approx(width, abs=2 * pixel_m)
    # the silhouette height models a dome as deep as wide (see
    # test_silhouette_height_of_a_dome_seen_from_above); a wall facing the camera (depth 0)
    # would read highest, so this wide, low plate reads at most its own height
    assert 0.0 <= row["height_m"] <= plate_h + 2 * pixel_m
    assert row["size_class"] == "obstacle"


def test_border_cut_rock_is_classed_from_its_height():
    # regression: a rock cut by the image border was classed on its visible width alone, a
    # lower bound; on runs/eval/mojave mojave_0008 object 28 (0.109 m wide, 0.020 m seen)
    # was a sample. Five whole plates 0.08 m wide and 0.024-0.040 m high (height / width
    # at most 0.5) and a plate cut by the left border, 0.07 m high
    heights = (0.024, 0.028, 0.032, 0.036, 0.040)
    xs = (-0.4, -0.2, 0.0, 0.2, 0.4)
    whole = [(x, 1.6, 0.08, h, 60) for x, h in zip(xs, heights, strict=True)]
    (desc, _, _), (labels, _) = _run([*whole, (-0.80, 1.6, 0.14, 0.07, 60)])
    cut = _row(desc, 6)
    assert cut["touches_border"] and cut["width_m"] < 0.10 and cut["height_max_m"] < 0.10
    assert cut["size_class"] == "obstacle"
    for k in range(1, 6):  # the whole plates keep their class
        assert not _row(desc, k)["touches_border"] and _row(desc, k)["size_class"] == "sample"
    (desc, _, _), _ = _run([*whole, (-0.80, 1.6, 0.14, 0.07, 60)], border_height_quantile=0)
    assert _row(desc, 6)["size_class"] == "sample"


def test_size_class_borderline_of_plates_near_and_far_from_the_limits():
    # a band of 0.3 x 0.10 m = 3 cm around each limit, pixels of 8 mm at 1.6 m: a plate
    # 5 cm wide and 3 cm high (a sure sample), one 10 cm wide (its width at the limit: its
    # class is chance), one 10 cm high (its height at the limit), one 30 x 20 cm (a sure
    # obstacle)
    plates = [
        (-0.4, 1.6, 0.05, 0.03, 60),
        (-0.1, 1.6, 0.10, 0.05, 60),
        (0.2, 1.6, 0.05, 0.10, 60),
        (0.5, 1.6, 0.30, 0.20, 60),
    ]
    (desc, _, _), _ = _run(plates, borderline_fraction=0.3)
    assert not desc["touches_border"].any()
    np.testing.assert_array_equal(desc["size_class_borderline"], [False, True, True, False])
    assert desc["size_class"][0] == "sample" and desc["size_class"][3] == "obstacle"
    (desc, _, _), _ = _run(plates, borderline_fraction=0)
    assert not desc["size_class_borderline"].any()
    assert DESCRIPTOR_SCHEMA.field("size_class_borderline").type == pa.bool_()


def test_size_class_borderline_of_a_border_cut_rock_is_of_its_bound():
    # the scene of test_border_cut_rock_is_classed_from_its_height: the cut plate's visible
    # width (about 3 cm) and height (about 6 cm) lie within a band of 0.5 x 0.10 m around
    # a limit, but its width bound from the height (over 15 cm) lies beyond it: a sure
    # obstacle once classed on the bound
    heights = (0.024, 0.028, 0.032, 0.036, 0.040)
    xs = (-0.4, -0.2, 0.0, 0.2, 0.4)
    plates = [(x, 1.6, 0.08, h, 60) for x, h in zip(xs, heights, strict=True)]
    plates.append((-0.80, 1.6, 0.14, 0.07, 60))
    (desc, _, _), _ = _run(plates, borderline_fraction=0.5)
    cut = _row(desc, 6)
    assert cut["touches_border"] and cut["size_class"] == "obstacle"
    assert not cut["size_class_borderline"]
    (desc, _, _), _ = _run(plates, borderline_fraction=0.5, border_height_quantile=0)
    cut = _row(desc, 6)
    assert cut["size_class"] == "sample" and cut["size_class_borderline"]


def test_regression_frame_without_a_ground_frame_gave_obstacles_without_a_note():
    # no camera pose and no fitted plane: every object came out an 'obstacle' with NaN
    # positions, and describe said nothing
    labels, gray, disparity, rng, _ = plate_scene(CAMERA, SHAPE, [(0.0, 1.6, 0.05, 0.05, 60)])
    inputs = {
        "right": gray,
        "labels": labels,
        "disparity": disparity,
        "range": rng,
        "height": np.full(SHAPE, np.nan, np.float32),  # depth's, without a plane
        "ground_plane": np.full(4, np.nan),
    }
    bare = Camera(focal_px=CAMERA.focal_px, baseline_m=CAMERA.baseline_m)
    frame = FrameContext(frame_id="f0", archive="t", camera=bare)
    result = STAGE.run(inputs, frame=frame, params=STAGE.defaults())
    assert result.tables["descriptors"]["size_class"].tolist() == ["obstacle"]
    (note,) = result.notes
    assert "no ground frame" in note and "classed obstacle" in note and "pitch_deg" in note
    with_pose = FrameContext(frame_id="f0", archive="t", camera=CAMERA)
    assert STAGE.run(inputs, frame=with_pose, params=STAGE.defaults()).notes == []
