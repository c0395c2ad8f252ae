"""The plane a link bends in (daemon/arm/arm_network.py describe_arm ``across_axis``) is a
property of the arm's design, not of its calibration: a DH length a fraction of a millimetre
off must not turn it (issue 29: the UR5e's upper arm and forearm lie along their frame's x,
a tie between y and z, and the bench truth's 0.2 mm draw turned them 90 deg)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from daemon.arm.arm_network import describe_arm
from daemon.arm.description import Arm
from daemon.arm.loading import load_arm


def lengths_moved(arm: Arm, rng: np.random.Generator, sigma_mm: float) -> Arm:
    """The arm with every DH a and d moved by a normal draw of ``sigma_mm``."""
    joints = tuple(
        dataclasses.replace(
            joint,
            a_mm=joint.a_mm + sigma_mm * float(rng.normal()),
            d_mm=joint.d_mm + sigma_mm * float(rng.normal()),
        )
        for joint in arm.joints
    )
    return dataclasses.replace(arm, joints=joints)


@pytest.mark.parametrize("name", ["ur5e", "crs-a465"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_fraction_of_a_millimetre_does_not_turn_a_links_bending_plane(
    name: str, seed: int
) -> None:
    arm = load_arm(name)
    moved = lengths_moved(arm, np.random.default_rng(seed), 0.2)
    nominal = describe_arm(arm)
    drawn = describe_arm(moved)
    for link, other in zip(nominal.links, drawn.links, strict=True):
        assert np.allclose(link.across_axis, other.across_axis, atol=0.01), link.name
