"""The names of the four TF frames ``map`` -> ``odom`` -> ``base_link`` -> ``laser`` that ``export-bag`` writes and the
foxglove bridge serves: their defaults and their command-line options, one definition for ``export-bag`` (typer) and
``cso-runtime service foxglove_bridge`` (argparse), so that the two take the same flags with the same words.

Imported by the command line as it starts (typer reads an option's default and help from the command's signature):
no numpy here. ``bag_export.BagFrames`` holds the four names and checks them."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

MAP_FRAME, ODOM_FRAME, BASE_FRAME, LASER_FRAME = "map", "odom", "base_link", "laser"
"""The frames' default names (``bag_export.BagFrames``)."""


@dataclass(frozen=True)
class FrameOption:
    """One frame's command-line option."""

    frame: str
    """Which frame: ``map``, ``odom``, ``base`` or ``laser`` (the field of ``bag_export.BagFrames``)."""
    default: str
    help: str

    @property
    def flag(self) -> str:
        """``--map-frame``, ..."""
        return f"--{self.frame}-frame"

    @property
    def param(self) -> str:
        """The foxglove bridge's parameter it sets (``services.foxglove_bridge.map_frame``, ...), argparse's dest."""
        return f"{self.frame}_frame"


FRAME_OPTIONS = {
    option.frame: option
    for option in (
        FrameOption(
            "map", MAP_FRAME, "The map frame's name: /map, /plan, /goal_pose, /explore/frontiers and map -> odom on /tf_static"
        ),
        FrameOption("odom", ODOM_FRAME, "The odometry frame's name: /odom, odom -> base_link on /tf, map -> odom"),
        FrameOption(
            "base",
            BASE_FRAME,
            "The robot's base frame's name: /odom's child, odom -> base_link, base_link -> laser (base_footprint...)",
        ),
        FrameOption(
            "laser",
            LASER_FRAME,
            "The LiDAR's frame's name: /scan's header and base_link -> laser on /tf_static (the LIMO's ROS driver: laser_link)",
        ),
    )
}
"""The four frames' options, by frame (``map``, ``odom``, ``base``, ``laser``)."""


def add_frame_arguments(parser: argparse.ArgumentParser) -> None:
    """The four options on a service's parser; a flag not given leaves the profile's parameter (None)."""
    for option in FRAME_OPTIONS.values():
        parser.add_argument(
            option.flag,
            default=None,
            metavar="NAME",
            help=f"{option.help}; overrides the profile's {option.param} (default {option.default})",
        )


def frames_given(args: argparse.Namespace) -> dict[str, str]:
    """The parameters (``map_frame``, ...) that the options of ``add_frame_arguments`` set on the command line."""
    return {option.param: value for option in FRAME_OPTIONS.values() if (value := getattr(args, option.param, None)) is not None}
