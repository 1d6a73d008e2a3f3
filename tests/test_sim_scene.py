import pytest

from device.sim.scene import SceneError, get_scene, load_scene, scene_from_dict, scene_names

GOOD_WALL = {"from": [2.0, -1.0], "to": [2.0, 1.0]}


def test_every_builtin_scene_loads():
    names = scene_names()
    for required in ("wall", "room", "corridor", "clutter", "targets", "near", "far", "sunlight", "glossy-floor", "empty"):
        assert required in names
    for n in names:
        s = get_scene(n)
        assert s.name
    assert get_scene("sunlight").ambient == "sunlight"
    assert get_scene("empty").surfaces == ()
    assert {w.material.reflectivity for w in get_scene("targets").walls} == {0.1, 0.9}
    assert min(w.start[0] for w in get_scene("near").walls) < 0.05
    assert min(w.start[0] for w in get_scene("far").walls) > 3.5


def test_wall_parameters():
    s = get_scene("wall:distance=1.5,angle=30,reflectivity=0.1")
    w = s.walls[0]
    assert w.material.reflectivity == 0.1
    # the wall line's closest point to the origin is 1.5 m away in direction 30 deg
    import math
    ax, ay = w.start
    ex, ey = w.end[0] - ax, w.end[1] - ay
    dist = abs(ax * ey - ay * ex) / math.hypot(ex, ey)
    assert dist == pytest.approx(1.5)


@pytest.mark.parametrize(
    "doc,fragment",
    [
        ({"wall": [{**GOOD_WALL, "reflectivity": 1.5}]}, "wall[0]: 'reflectivity' = 1.5"),
        ({"wall": [GOOD_WALL, {"from": [1, 1]}]}, "wall[1]: missing required key 'to'"),
        ({"wall": [{**GOOD_WALL, "colour": "red"}]}, "wall[0]: unknown key(s) colour"),
        ({"wall": [{**GOOD_WALL, "z": [1.0, 0.0]}]}, "wall[0]: 'z'"),
        ({"wall": [{**GOOD_WALL, "texture": "marble"}]}, "wall[0]: 'texture' must be one of"),
        ({"box": [{"center": [1, 0], "size": [0, 1]}]}, "box[0]: 'size'"),
        ({"cylinder": [{"center": [1, 0], "radius": -1}]}, "cylinder[0]: 'radius'"),
        ({"floor": {"z": 0.2}}, "[floor]: 'z' = 0.2"),
        ({"floor": {"z": -0.1, "gloss": 1.0}}, "[floor]: 'gloss'"),
        ({"ambient": "moonlight"}, "'ambient' must be one of"),
        ({"wall": [{"from": [1, 1], "to": [1, 1]}]}, "wall[0]: 'from' and 'to' are the same point"),
        ({"walls": []}, "unknown key(s) walls"),
    ],
)
def test_validation_errors_name_the_field(doc, fragment):
    with pytest.raises(SceneError) as exc:
        scene_from_dict(doc, "my.toml")
    assert fragment in str(exc.value) and str(exc.value).startswith("my.toml")


def test_bad_files_and_names(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("wall = [")
    with pytest.raises(SceneError, match="not valid TOML"):
        load_scene(p)
    with pytest.raises(SceneError, match="no such scene file"):
        load_scene(tmp_path / "missing.toml")
    with pytest.raises(SceneError, match="unknown scene 'kitchen'"):
        get_scene("kitchen")
    with pytest.raises(SceneError, match="unknown parameter 'depth'"):
        get_scene("wall:depth=2")
    with pytest.raises(SceneError, match="'distance' must be positive"):
        get_scene("wall:distance=-1")
