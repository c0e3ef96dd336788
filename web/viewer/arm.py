"""The arm in one viewer's scene: the room floor, the subject's facing direction, the
thorax, clavicle, upper arm, forearm and hand as solid segments between the joint
centres, joints as spheres, and optional segment frames at the sensor sites.

Nodes are made once (``ArmView(...)``) and moved in place (``show``). Names: ``/floor``,
``/stance`` (below the hip on the floor, turned to the facing direction; its ``facing``
arrow and legs), ``/arm/thorax`` (the thorax frame at the sternal notch, world ENU pose) and
under it ``clavicle``, ``upper_arm``, ``forearm``, ``hand``, ``joints/*``, ``sensors/*``,
``trunk``, ``head`` and the other, resting ``other_arm/*``. Lengths [m], quaternions wxyz.
"""

from __future__ import annotations

import numpy as np
from armtrack.estimator.arm.joints import SEGMENTS
from armtrack.estimator.body import SegmentLengths

from .geometry import HIP_HEIGHT, between, heading, notch_in_world, quat, yaw_quat
from .pose import Pose
from .rom import label_scale

ROOT = "/arm/thorax"

SKIN = (232, 190, 160)
LIMB = (70, 140, 220)
JOINT = (250, 250, 250)
TRUNK = (150, 165, 190)
REST = (195, 195, 200)
FACING = (30, 30, 30)


class ArmView:
    """The arm of one viewer: ``scene`` is that viewer's ``client.scene``; ``height_m`` the
    subject's body height [m] (the trunk, head and legs are drawn in proportion);
    ``display_scale``: how much the page shows the view scaled down (``rom.label_scale``)."""

    def __init__(self, scene, height_m: float, lengths: SegmentLengths, side_sign: float,
                 display_scale: float = 1.0):
        self.scene = scene
        self.height_m = h = height_m
        self.lengths = lengths
        self.side_sign = side_sign
        k = h / 1.75  # thicknesses scale with the body
        self.floor = scene.add_grid("/floor", width=4.0, height=4.0, plane="xy", cell_size=0.25,
                                    section_size=1.0, plane_color=(245, 245, 245),
                                    plane_opacity=0.6, shadow_opacity=0.2)
        self.stance = scene.add_frame("/stance", show_axes=False,
                                      position=(0.0, 0.0, 0.0))
        scene.add_arrows("/stance/facing", np.array([[[0.15, 0, 0.005], [0.75, 0, 0.005]]]),
                         FACING, shaft_radius=0.012, head_radius=0.035, head_length=0.08)
        scene.add_label("/stance/facing/label", "facing", position=(0.8, 0.0, 0.02),
                        font_screen_scale=label_scale(0.7, display_scale))
        hip = HIP_HEIGHT * h
        for name, z in (("left", 0.05 * h), ("right", -0.05 * h)):  # stance frame: y left
            centre, wxyz, length = between(np.array([0.0, z, hip]), np.array([0.0, z, 0.02]))
            scene.add_cylinder(f"/stance/legs/{name}", radius=0.06 * k, height=length,
                               color=REST, position=centre, wxyz=wxyz)

        self.thorax = scene.add_frame(ROOT, show_axes=False)
        # the trunk hangs from the sternal notch (thorax frame: X front, Y up, Z right)
        scene.add_box(f"{ROOT}/trunk", color=TRUNK,
                      dimensions=(0.11 * h, 0.288 * h * 0.92, 1.45 * lengths.clavicle),
                      position=(-0.055 * h, -0.144 * h, 0.0))
        centre, wxyz, length = between(np.zeros(3), np.array([-0.01 * h, 0.06 * h, 0.0]))
        scene.add_cylinder(f"{ROOT}/neck", radius=0.03 * k, height=length, color=SKIN,
                           position=centre, wxyz=wxyz)
        scene.add_icosphere(f"{ROOT}/head", radius=0.062 * h, color=SKIN,
                            position=(-0.02 * h, 0.118 * h, 0.0))
        self._add_other_arm(k)

        radius = {"clavicle": 0.022 * k, "upper_arm": 0.045 * k, "forearm": 0.036 * k}
        self.segments = {name: scene.add_cylinder(f"{ROOT}/{name}", radius=r, height=0.1,
                                                  color=LIMB if name != "clavicle" else TRUNK)
                         for name, r in radius.items()}
        self.hand = scene.add_box(f"{ROOT}/hand", color=SKIN,
                                  dimensions=(0.09 * k, lengths.hand, 0.03 * k))
        self.joints = {name: scene.add_icosphere(f"{ROOT}/joints/{name}", radius=r * k,
                                                 color=JOINT)
                       for name, r in (("shoulder", 0.05), ("elbow", 0.042), ("wrist", 0.035))}
        self.sensors = {s: scene.add_frame(f"{ROOT}/sensors/{s}", axes_length=0.07 * k,
                                           axes_radius=0.005 * k, visible=False)
                        for s in SEGMENTS}
        self._heights: dict[str, float] = {}

    def _add_other_arm(self, k: float) -> None:
        """The other arm, resting along the trunk (not measured)."""
        z = -self.side_sign * self.lengths.clavicle
        down = np.array([0.0, -1.0, 0.0])
        shoulder = np.array([0.0, 0.0, z])
        elbow = shoulder + self.lengths.upper_arm * down
        wrist = elbow + self.lengths.forearm * down
        hand = wrist + self.lengths.hand * down
        for name, (a, b), r in (("upper_arm", (shoulder, elbow), 0.045),
                                ("forearm", (elbow, wrist), 0.036),
                                ("hand", (wrist, hand), 0.028)):
            centre, wxyz, length = between(a, b)
            self.scene.add_cylinder(f"{ROOT}/other_arm/{name}", radius=r * k, height=length,
                                    color=REST, position=centre, wxyz=wxyz)
        self.scene.add_icosphere(f"{ROOT}/other_arm/shoulder", radius=0.048 * k, color=REST,
                                 position=shoulder)

    def set_sensor_frames(self, visible: bool) -> None:
        for frame in self.sensors.values():
            frame.visible = visible

    def notch_world(self, pose: Pose) -> np.ndarray:
        """The sternal notch [m, world] of ``pose``."""
        return notch_in_world(pose.R_world["thorax"], self.height_m)

    def show(self, pose: Pose) -> None:
        """Move the nodes to ``pose`` (call inside the client's ``atomic()``)."""
        R_world_thorax = pose.R_world["thorax"]
        self.stance.wxyz = yaw_quat(heading(R_world_thorax))
        self.thorax.wxyz = quat(R_world_thorax)
        self.thorax.position = self.notch_world(pose)
        p = pose.p_thorax
        ends = {"clavicle": (np.zeros(3), p["shoulder"]),
                "upper_arm": (p["shoulder"], p["elbow"]),
                "forearm": (p["elbow"], p["wrist"])}
        known = {k: bool(np.isfinite(v).all()) for k, v in p.items()}
        R_thorax = pose.R_thorax
        # a segment whose sensor stopped sending is unknown (NaN): left out, not drawn wrong
        for name, (a, b) in ends.items():
            node = self.segments[name]
            shown = bool(np.isfinite(a).all() and np.isfinite(b).all())
            if node.visible != shown:
                node.visible = shown
            if not shown:
                continue
            centre, wxyz, length = between(a, b)
            node.position, node.wxyz = centre, wxyz
            if abs(self._heights.get(name, -1.0) - length) > 1e-3:
                node.height = self._heights[name] = length
        hand_shown = known["wrist"] and known["hand"] and bool(
            np.isfinite(R_thorax["hand"]).all())
        if self.hand.visible != hand_shown:
            self.hand.visible = hand_shown
        if hand_shown:
            self.hand.wxyz = quat(R_thorax["hand"])
            self.hand.position = (p["wrist"] + p["hand"]) / 2
            hand_length = float(np.linalg.norm(p["hand"] - p["wrist"]))
            if abs(self._heights.get("hand", -1.0) - hand_length) > 1e-3:
                self._heights["hand"] = hand_length
                self.hand.dimensions = (self.hand.dimensions[0], hand_length,
                                        self.hand.dimensions[2])
        for name, node in self.joints.items():
            if node.visible != known[name]:
                node.visible = known[name]
            if known[name]:
                node.position = p[name]
        sites = {"thorax": np.array([0.0, -0.09 * self.height_m, 0.0]),
                 "clavicle": p["shoulder"] / 2,
                 "upper_arm": (p["shoulder"] + p["elbow"]) / 2,
                 "forearm": p["elbow"] + 0.7 * (p["wrist"] - p["elbow"]),
                 "hand": (p["wrist"] + p["hand"]) / 2}
        for name, frame in self.sensors.items():
            if np.isfinite(R_thorax[name]).all() and np.isfinite(sites[name]).all():
                frame.wxyz = quat(R_thorax[name])
                frame.position = sites[name]
