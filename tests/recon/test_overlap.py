"""The object's triangles against the furniture boxes: exact overlap, its depth and the warning."""
import logging

import numpy as np
import pytest

from recon.overlap import furniture_boxes, furniture_overlaps, mesh_box_overlap
from recon.scene import box_quads

# A unit cube's 12 outward triangles over its 8 corners (index bits: x, y, z).
CUBE_V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
CUBE_F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
ROOM = (np.zeros(3), np.array([5.0, 2.6, 4.0]))


def _table(yaw_deg=0.0, center=(3.3, 0.73, 0.35), size=(1.4, 0.04, 0.7)):
    return box_quads("table_top", np.array(center), np.array(size), np.radians(yaw_deg), np.full(3, 0.5),
                     "furniture", *ROOM)


def _cube(lo, size=0.3):
    return CUBE_V * size + np.asarray(lo, float)


def test_box_through_the_table_top_no_vertex_inside():
    # 0.3 m cube from y 0.70 to 1.00 through the top (0.71-0.75): no corner lies inside it, its
    # side faces cross it; pushing it 5 cm up (to 0.75) frees it, 29 cm down the other way.
    v = _cube([3.0, 0.70, 0.2])
    b = furniture_boxes(_table())[0]
    assert not np.any(np.all((v > b.centre - b.half) & (v < b.centre + b.half), axis=1))
    o = mesh_box_overlap(v, CUBE_F, b)
    assert o.name == "table_top"
    assert o.depth == pytest.approx(0.05, abs=1e-9)
    np.testing.assert_allclose(o.push, [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("lo, depth", [([3.0, 0.75, 0.2], None),          # resting on the top
                                       ([3.0, 0.4, 0.2], None),           # under it, the top touching
                                       ([4.1, 0.6, 0.2], None),           # beside it
                                       ([3.0, 0.74, 0.2], 0.01),          # sunk 1 cm into the top
                                       ([3.0, 0.42, 0.2], 0.01),          # from below, 1 cm into it
                                       ([3.0, 0.45, 0.2], 0.04)])         # from below, its top flush
def test_depth_of_the_overlap(lo, depth):
    o = mesh_box_overlap(_cube(lo), CUBE_F, furniture_boxes(_table())[0])
    if depth is None:
        assert o is None or o.depth < 1e-9, o
    else:
        assert o.depth == pytest.approx(depth, abs=1e-9)


def test_turned_box_pushed_along_its_own_axis():
    # A 1 m box turned 30 degrees about +Y; a 0.2 m cube whose centre lies 0.05 m inside its +x'
    # face, aligned with it: freed by 0.05 + 0.1 = 0.15 m along +x' (the turned axis).
    yaw = np.radians(30.0)
    quads = box_quads("cabinet", np.array([2.0, 0.5, 2.0]), np.ones(3), yaw, np.full(3, 0.5), "furniture", *ROOM)
    b = furniture_boxes(quads)[0]
    np.testing.assert_allclose(np.sort(b.half), [0.5, 0.5, 0.5], atol=1e-12)
    ax = np.array([np.cos(yaw), 0.0, -np.sin(yaw)])  # rot_y(yaw) @ +x
    r = np.array([ax, [0, 1, 0], np.cross(ax, [0, 1, 0])])
    v = (CUBE_V - 0.5) * 0.2 @ r + np.array([2.0, 0.5, 2.0]) + (0.5 - 0.05) * ax
    o = mesh_box_overlap(v, CUBE_F, b)
    assert o.depth == pytest.approx(0.15, abs=1e-9)
    np.testing.assert_allclose(o.push, ax, atol=1e-9)


def test_only_boxes_cut_deeper_than_the_tolerance_are_named():
    quads = _table() + box_quads("shelf", np.array([4.79, 0.9, 2.7]), np.array([0.42, 1.8, 0.9]), 0.0,
                                 np.full(3, 0.5), "furniture", *ROOM)
    v = _cube([3.0, 0.70, 0.2])
    assert [o.name for o in furniture_overlaps(v, CUBE_F, quads, min_depth=0.01)] == ["table_top"]
    assert furniture_overlaps(_cube([3.0, 0.745, 0.2]), CUBE_F, quads, min_depth=0.01) == []


def test_composite_warns_naming_the_table_and_the_depth(tmp_path, caplog):
    """`composite --place` with a box pushed through the demo desk's top (y 0.71-0.75 m) by its
    faces only: one warning naming 'desk_top' and 5.0 cm; resting on it: none."""
    import open3d as o3d

    from app.cli import demo_scene_dir
    from app.composite import place_object
    from recon.scene import load_scene

    mesh = tmp_path / "box.ply"
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(CUBE_V * 0.3), o3d.utility.Vector3iVector(CUBE_F))
    m.compute_vertex_normals()
    assert o3d.io.write_triangle_mesh(str(mesh), m)
    scene = load_scene(demo_scene_dir())
    with caplog.at_level(logging.WARNING, logger="photoar"):
        place_object(scene, mesh, [3.15, 0.70, 0.35], 0.0, object_size=0.3)
    lines = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(lines) == 1 and "box.ply" in lines[0] and "5.0 cm into furniture 'desk_top'" in lines[0], lines
    assert "5.0 cm up" in lines[0], lines
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="photoar"):
        place_object(scene, mesh, [3.15, 0.75, 0.35], 0.0, object_size=0.3)
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == []
