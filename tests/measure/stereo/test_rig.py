"""One rig class (measure.stereo.rig.Rig): a pair built by StereoRig is a rig of two that keeps
its pair port; a rig built from ports has N ≥ 1 cameras; equality and hashing by value; the
pair's conveniences only on a pair."""

from __future__ import annotations

import numpy as np
import pytest

from measure import Rig, StereoRig
from measure.geometry.camera import Camera
from measure.geometry.dome import DomePair, DomePort
from measure.geometry.flat_pair import FlatPair
from measure.geometry.port import FlatPort, index_matched_port
from measure.stereo.multirig import MultiRig, ViewPorts
from measure.stereo.pose import as_views

K = np.array([[1100.0, 0, 1223.5], [0, 1100.0, 1023.5], [0, 0, 1.0]])
SIZE = (2448, 2048)
PORT = FlatPort((0, 0, 1), 100.0, (5.0,), (1.0, 1.54, 1.33))
LEFT = Camera(K, SIZE)
RIGHT = Camera(K, SIZE, t=(200.0, 0.0, 0.0))
THIRD = Camera(K, SIZE, t=(400.0, 0.0, 0.0))
DOMES = DomePair(DomePort((0.0, 0.0, 5.0), 60.0, 8.0, (1.0, 1.5, 1.33)),
                 DomePort((200.0, 0.0, 5.0), 60.0, 8.0, (1.0, 1.5, 1.33)))
HOUSINGS = FlatPair(PORT, PORT.replace(distance=90.0))


@pytest.mark.parametrize("port", [PORT, DOMES, HOUSINGS, ViewPorts(PORT, DOMES.right)],
                         ids=["shared", "domes", "housings", "view ports"])
def test_a_pair_is_a_rig_of_two_that_keeps_its_port(port):
    rig = StereoRig(LEFT, RIGHT, port)
    assert type(rig) is Rig and MultiRig is Rig
    assert rig.port is port and rig.ports == (port.view(0), port.view(1))
    assert rig.view_port(0) is port.view(0) and rig.view_port(1) is port.view(1)
    assert (rig.left, rig.right) == rig.cameras == (LEFT, RIGHT)
    assert rig.names == ("left", "right") and len(rig) == 2
    assert np.array_equal(rig.depth_axis, port.depth_axis(LEFT))
    assert rig == StereoRig(LEFT, RIGHT, port) and hash(rig) == hash(StereoRig(LEFT, RIGHT, port))
    other = PORT.replace(distance=95.0)
    moved = rig.with_port(other)
    assert moved.port is other and moved.cameras == rig.cameras and moved.names == rig.names


def test_no_port_is_the_pairs_index_matched_port():
    rig = StereoRig(LEFT, RIGHT)
    expected = index_matched_port(LEFT.R[:, 2], np.stack([LEFT.center, RIGHT.center]))
    assert rig.port == expected and rig.ports == (expected, expected)
    assert not rig.refracts and StereoRig(LEFT, RIGHT, PORT).refracts
    # built from ports, both cameras in air: the same pair port, each camera its own stand-in
    in_air = Rig((LEFT, RIGHT), (None, None))
    assert in_air.port == expected and in_air.ports == (None, None)
    assert in_air.pair(0, 1) == rig and in_air != rig


def test_a_rig_of_two_from_ports_has_the_port_of_its_pair():
    shared = Rig((LEFT, RIGHT), (PORT, PORT))
    assert shared.port == PORT and shared == StereoRig(LEFT, RIGHT, PORT)
    domes = Rig((LEFT, RIGHT), (DOMES.left, DOMES.right))
    assert domes.port == ViewPorts(DOMES.left, DOMES.right) == domes.pair(0, 1).port
    assert domes != StereoRig(LEFT, RIGHT, DOMES)  # a DomePair is not a pair of view ports
    assert domes.stereo() == StereoRig(LEFT, RIGHT, DOMES)


def test_one_camera_and_n_cameras():
    one = Rig([LEFT], [PORT])
    assert one.names == ("cam0",) and len(one) == 1 and one.port is None
    assert [view.port for view in one.views()] == [PORT]
    assert one.trace(0, np.array([[0.0, 0.0, 1.0]])).directions.shape == (1, 3)
    with pytest.raises(ValueError, match="at least one camera"):
        Rig([], [])
    three = Rig([LEFT, RIGHT, THIRD], [PORT, PORT, None], ["a", "b", "c"])
    assert three.port is None and three.pair(0, 1).port == PORT
    for missing in ("left", "right", "depth_axis"):
        with pytest.raises(AttributeError, match="only a rig of two cameras"):
            getattr(three, missing)
    assert getattr(one, "left", None) is None
    assert [view.port for view in as_views(three)] == [PORT, PORT, three.view_port(2)]
    with pytest.raises(ValueError, match="camera name 'a' is given twice"):
        Rig([LEFT, RIGHT], [PORT, PORT], ["a", "a"])
