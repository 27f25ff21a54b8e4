"""The mounting pose of a robot's holds: which holds a one-orientation fit may use.

A robot on its wheels stops level or on slopes. The single-orientation models describe one
pose, and holds on a slope would look like drift to them, so a lifelong fit keeps the holds
within a few degrees of the mounting pose (the direction with the most sample weight).
Angles in degrees; no ROS import.
"""

from ..collection.segments import family_direction, main_direction, mounting_pose_mask

#: a robot on its wheels: one orientation family while every hold is within this angle of
#: the mounting pose (degrees; the angle ``collection.segments.distinct_orientations`` tells
#: orientations apart by)
FAMILY_DEG = 20.0


def pose_of(windows):
    """Return the sample-weighted mean gravity-up direction of the most common pose."""
    return main_direction(windows)


def main_pose(windows, pose_deg, reference=None):
    """Return the windows of the holds within ``pose_deg`` of the mounting pose.

    Only when the holds form one orientation family (``one_family``: a robot on its
    wheels, level or on slopes): the single-orientation models describe one pose, and
    holds on a slope would look like drift to them. With several orientations (or no
    holds) the windows are returned as they are.
    """
    return windows.select(main_pose_mask(windows, pose_deg, reference))


def main_pose_mask(windows, pose_deg, reference=None):
    """Return the (n,) mask of the windows ``main_pose`` keeps.

    ``collection.segments.mounting_pose_mask``, which ``calibrate`` applies to every
    one-orientation log too (``estimation.calibrate``).
    """
    return mounting_pose_mask(windows, pose_deg, reference, FAMILY_DEG)


def one_family(windows):
    """Return True when every hold is within ``FAMILY_DEG`` of the mounting pose.

    Measured from the mounting pose, not hold to hold (``family_direction``): slopes of up
    to 12 deg either way are up to 24 deg apart from each other, and counted pairwise
    (``distinct_orientations`` before 2026-11-29, which also depended on the order of the
    holds) they made a robot's level stops and slopes "two orientations", so the lifelong
    fit took the slopes in and every estimate was refused for missing faces (simulated
    month, seed 22, from day 17 on).
    """
    return family_direction(windows, FAMILY_DEG) is not None
