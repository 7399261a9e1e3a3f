"""Interactive camera: orbit / pan / zoom around a pivot, and fly (WASD/QE) -- pure numpy.

State: the world->camera rotation ``R`` (OpenCV rows: right, down, forward), the eye
position, the distance to the orbit pivot (which lies ``distance`` ahead of the eye), the
vertical focal length relative to the image height (kept when the window is resized), and the
scene's up vector (orbit yaws about it and pitch stops short of it, so the horizon never
flips).  :meth:`CameraController.camera` turns the state into a
:class:`~gsz.evaluation.cameras.Camera` of any image size; :meth:`snap_to` adopts a dataset
camera exactly (a snapped view renders the same pixels as gsz-eval's view of that camera when
the window has the camera's size).
"""
from __future__ import annotations

import math

import numpy as np

from ..evaluation.cameras import Camera

__all__ = ["CameraController", "rotation_about"]

#: closest the view direction may come to straight up / down while orbiting (degrees)
_POLE_MARGIN_DEG = 3.0


def rotation_about(axis, angle: float) -> np.ndarray:
    """[3, 3] rotation by ``angle`` radians about unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * (K @ K)


class CameraController:
    """Mutable view state; every change bumps :attr:`version`.

    up            [3] world up vector (e.g. (0, -1, 0) for the usual y-down 3DGS frames)
    orbit_speed   radians per pixel of drag
    """

    def __init__(self, camera: Camera, pivot_distance: float, up, *, orbit_speed: float = 0.005):
        self.up = np.asarray(up, np.float64) / np.linalg.norm(up)
        self.orbit_speed = float(orbit_speed)
        self.version = 0
        self.snap_to(camera, pivot_distance)
        self._home = (self.R.copy(), self.eye.copy(), self.distance, self.f_rel, self.aspect_fx)

    # -- state -----------------------------------------------------------------------------------
    def snap_to(self, camera: Camera, pivot_distance: float | None = None) -> None:
        """Adopt ``camera``'s pose and vertical field of view (fy / height)."""
        self.R = np.array(camera.R, np.float64)
        self.eye = np.array(camera.center, np.float64)
        if pivot_distance is not None and pivot_distance > 0:
            self.distance = float(pivot_distance)
        self.f_rel = camera.fy / camera.height
        self.aspect_fx = camera.fx / camera.fy
        self._snapped = camera
        self.version += 1

    def reset(self) -> None:
        """Back to the initial view."""
        R, eye, dist, f_rel, afx = self._home
        self.R, self.eye, self.distance, self.f_rel, self.aspect_fx = R.copy(), eye.copy(), dist, f_rel, afx
        self._snapped = None
        self.version += 1

    @property
    def forward(self) -> np.ndarray:
        return self.R[2]

    @property
    def pivot(self) -> np.ndarray:
        return self.eye + self.distance * self.forward

    def camera(self, width: int, height: int) -> Camera:
        """The current view as a Camera of ``width`` x ``height`` pixels (principal point at
        the centre; vertical field of view kept, square pixels unless the snapped camera's
        were not).  At the snapped camera's own size the snapped camera comes back exactly."""
        s = self._snapped
        if s is not None and (width, height) == (s.width, s.height):
            return Camera(self.R, -self.R @ self.eye, s.fx, s.fy, s.cx, s.cy, width, height, s.name)
        fy = self.f_rel * height
        return Camera(self.R, -self.R @ self.eye, fy * self.aspect_fx, fy, width / 2.0, height / 2.0,
                      int(width), int(height), "view")

    def _set_pose(self, R, eye):
        # Re-orthonormalise to stop drift over thousands of small rotations.
        u, _, vt = np.linalg.svd(R)
        self.R = u @ vt
        self.eye = np.asarray(eye, np.float64)
        self._snapped = None
        self.version += 1

    def _rotate_world(self, rot: np.ndarray, centre: np.ndarray) -> None:
        """Turn the camera by world rotation ``rot`` about the point ``centre``."""
        self._set_pose(self.R @ rot.T, centre + rot @ (self.eye - centre))

    def _clamped_pitch(self, angle: float) -> float:
        """``angle`` cut so the view direction stays inside the pole margins: the camera is
        turned by ``-angle`` about its right axis, which adds ``angle`` to the angle between
        the view direction and the up vector."""
        cur = math.acos(float(np.clip(self.forward @ self.up, -1.0, 1.0)))
        lo = math.radians(_POLE_MARGIN_DEG)
        hi = math.pi - lo
        return float(np.clip(angle, min(0.0, lo - cur), max(0.0, hi - cur)))

    # -- interactions ----------------------------------------------------------------------------
    def orbit(self, dx_px: float, dy_px: float) -> None:
        """Drag by (dx, dy) pixels: yaw about the up axis and pitch about the camera's right
        axis, both around the pivot (the scene turns with the mouse)."""
        self._turn(dx_px, dy_px, self.pivot)

    def look(self, dx_px: float, dy_px: float) -> None:
        """Fly-mode mouse look: the same rotation about the eye instead of the pivot."""
        self._turn(dx_px, dy_px, self.eye.copy())

    def _turn(self, dx_px: float, dy_px: float, centre: np.ndarray) -> None:
        yaw = -dx_px * self.orbit_speed
        pitch = self._clamped_pitch(dy_px * self.orbit_speed)
        rot = rotation_about(self.up, yaw)
        if pitch:
            right = rot @ self.R[0]
            rot = rotation_about(right, -pitch) @ rot
        self._rotate_world(rot, centre)

    def pan(self, dx_px: float, dy_px: float, height_px: int) -> None:
        """Move the eye and pivot in the image plane so the pivot follows the mouse."""
        per_px = self.distance / max(self.f_rel * height_px, 1e-9)
        d = -dx_px * per_px * self.R[0] - dy_px * per_px * self.R[1]
        self._set_pose(self.R, self.eye + d)

    def zoom(self, steps: float) -> None:
        """Scroll: move towards the pivot by 10 % of the distance per step (out for < 0)."""
        pivot = self.pivot
        self.distance = float(max(self.distance * (0.9 ** steps), 1e-6))
        self._set_pose(self.R, pivot - self.distance * self.forward)

    def fly(self, right: float, up: float, forward: float, step: float) -> None:
        """Translate by ``step`` world units along camera right / scene up / camera forward
        (each of right, up, forward in [-1, 1]); the pivot moves along."""
        v = right * self.R[0] + up * self.up + forward * self.forward
        n = np.linalg.norm(v)
        if n == 0 or step == 0:
            return
        self._set_pose(self.R, self.eye + v / n * step)
