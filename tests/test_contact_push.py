"""``sensors.contact_push``: the direction in which one set of collision elements is pushed by
another, and ``sensors.deepest_penetration``, their largest overlap, checked on boxes whose
contact normals and overlaps are known from the geometry."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from wirecraft.sensors import contact_push, deepest_penetration, geom_ids

BOXES = """
<mujoco>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <geom name="wall" type="box" size="0.01 0.2 0.2" pos="0.1 0 0.2"/>
    <body name="box" pos="0.08 0 0.0095">
      <freejoint/>
      <geom name="box" type="box" size="0.01 0.01 0.01"/>
    </body>
  </worldbody>
</mujoco>
"""


@pytest.fixture()
def resting_box():
    """A box sunk 0.5 mm into the floor and 0.5 mm into the wall at +x (contacts, no step)."""
    model = mujoco.MjModel.from_xml_string(BOXES)
    data = mujoco.MjData(model)
    data.qpos[0] = 0.0805
    mujoco.mj_forward(model, data)
    return model, data


def test_the_floor_pushes_the_box_up_and_the_wall_pushes_it_back(resting_box):
    model, data = resting_box
    box, floor, wall = (geom_ids(model, [name]) for name in ("box", "floor", "wall"))
    up = contact_push(data, box, floor)
    assert np.linalg.norm(up) > 0
    np.testing.assert_allclose(up / np.linalg.norm(up), [0, 0, 1], atol=1e-9)
    back = contact_push(data, box, wall)
    np.testing.assert_allclose(back / np.linalg.norm(back), [-1, 0, 0], atol=1e-9)
    # Either order of the pair: the box pushes the floor down.
    down = contact_push(data, floor, box)
    np.testing.assert_allclose(down / np.linalg.norm(down), [0, 0, -1], atol=1e-9)
    # Everything the box touches: back and up together.
    both = contact_push(data, box, None)
    assert both[0] < 0 and both[2] > 0 and abs(both[1]) < 1e-9


def test_no_contact_no_push(resting_box):
    model, data = resting_box
    data.qpos[2] = 0.5  # lifted clear of everything
    mujoco.mj_forward(model, data)
    box, floor = geom_ids(model, ["box"]), geom_ids(model, ["floor"])
    np.testing.assert_array_equal(contact_push(data, box, floor), np.zeros(3))


def test_deepest_penetration_is_the_overlap_set_by_the_geometry(resting_box):
    model, data = resting_box
    data.qpos[2] = 0.008  # the 1 cm box's centre 8 mm up: 2 mm into the floor
    mujoco.mj_forward(model, data)
    box, floor, wall = (geom_ids(model, [name]) for name in ("box", "floor", "wall"))
    assert deepest_penetration(data, box, floor) == pytest.approx(0.002, abs=1e-9)
    assert deepest_penetration(data, wall, box) == pytest.approx(0.0005, abs=1e-9)
    assert deepest_penetration(data, box) == pytest.approx(0.002, abs=1e-9)
    data.qpos[2] = 0.5
    mujoco.mj_forward(model, data)
    assert deepest_penetration(data, box, floor) == 0.0
