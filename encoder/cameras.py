"""Pinhole cameras: the :class:`Camera` contract shared by the renderer, metrics and viewer.

Convention (OpenCV / COLMAP): camera x right, y down, z forward (looking along +z);
``x_cam = R @ x_world + t``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Camera:
    """One pinhole view.

    R      [3, 3] float64  world -> camera rotation
    t      [3]    float64  world -> camera translation (x_cam = R @ x_world + t)
    fx, fy float           focal lengths in pixels
    cx, cy float           principal point in pixels (pixel centres at integer + 0.5)
    width, height int      image size in pixels
    name   str
    """

    R: np.ndarray
    t: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    name: str = ""

    def __post_init__(self):
        self.R = np.asarray(self.R, dtype=np.float64).reshape(3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(3)
        self.fx, self.fy, self.cx, self.cy = map(float, (self.fx, self.fy, self.cx, self.cy))
        self.width, self.height = int(self.width), int(self.height)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, -R^T t."""
        return -self.R.T @ self.t

    @property
    def world_to_camera(self) -> np.ndarray:
        """[4, 4] float64 homogeneous world -> camera matrix."""
        m = np.eye(4)
        m[:3, :3] = self.R
        m[:3, 3] = self.t
        return m

    def scaled(self, width: int) -> "Camera":
        """The same view at another image width (height and intrinsics scaled to match)."""
        s = width / self.width
        return Camera(self.R, self.t, self.fx * s, self.fy * s, self.cx * s, self.cy * s,
                      int(round(width)), max(1, int(round(self.height * s))), self.name)
