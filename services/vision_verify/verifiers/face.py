"""Face verifier (seed 002, Bellotto & Hu): OpenCV's Haar cascade, bearing and elevation.

A face found at image centre (u, v) has, for a pinhole camera (seed 002 eq. 1),

    alpha = atan((W/2 - u) / f)   (bearing, left positive)
    beta  = atan((v - H/2) / f)   (elevation below the optical axis)

A candidate at camera-frame (x_c, y_c), range rho = |(x_c, y_c)|, predicts a face at bearing
atan2(y_c, x_c) and, for a face centre at height z, elevation atan((h_cam - z) / rho) (seed 002
eq. 6 with no tilt). The model is the target's face height z_model (measured at acquisition
when a face is seen in the model rectangle, else ``face_height_m``). A candidate's distance is
the Mahalanobis distance of the nearest face's (alpha, beta) residual with
sigma_alpha = sigma_beta = pi/45 (seed 002), divided by the gate ``gate`` (seed 002:
lambda_C = 3.37), so a face inside the gate gives a distance <= 1; a candidate with no face
inside the gate gets ``no_face_distance``: by default None, no evidence either way. A face is
positive evidence only (seed 002 uses it to confirm a person): someone walking away shows
none, and a rejection for that made the tracker drop a target it was following correctly
(the bellotto preset tracked 1-2 % of the visible time in the simulator, whose faces the Haar
cascade does not find).

A face says "a person faces the camera here" and, through its height, a little about who it
is; it cannot tell two people of the same height apart, and sees nothing of a person walking
away from the camera. docs/vision_verify.md has its figures.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import cv2
import msgspec
import numpy as np

from ..core import ImageFeatures, Model, Rect, View

__all__ = ["FaceSettings", "FaceVerifier"]


class FaceSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    cascade: str = "haarcascade_frontalface_default.xml"
    """A file name in cv2.data.haarcascades, or a path."""
    scale_factor: float = 1.1
    """The Haar cascade's scale step between detection sizes (OpenCV detectMultiScale
    scaleFactor; smaller finds more faces, slower)."""
    min_neighbors: int = 3
    """Overlapping detections a face needs to count (detectMultiScale minNeighbors; more:
    fewer false faces)."""
    min_face_px: int = 12
    """Smallest face searched for (px, square; detectMultiScale minSize)."""
    sigma_bearing_rad: float = math.pi / 45  # seed 002 III-A: sigma_alpha = pi/45
    sigma_elevation_rad: float = math.pi / 45  # seed 002 III-A: sigma_beta = pi/45
    gate: float = 3.37  # seed 002 III-C: lambda_C = 3.37
    face_height_m: float = 1.6
    """Face-centre height assumed when no face is seen at acquisition."""
    no_face_distance: float | None = None
    """Distance of a candidate with no face in its gate; None: not judged (no evidence). A
    number (e.g. 2.0, above the threshold) makes "no face" a rejection."""
    default_threshold: float = 1.0
    """Rejection threshold on the face distance when the node's ``threshold`` is unset."""


class FaceVerifier:
    name = "face"
    settings_type = FaceSettings

    def __init__(self, settings: FaceSettings | None = None) -> None:
        self.settings = s = settings or FaceSettings()
        path = (
            s.cascade
            if os.path.sep in s.cascade
            else os.path.join(cv2.data.haarcascades, s.cascade)
        )
        self._cascade = cv2.CascadeClassifier(path)
        if self._cascade.empty():
            raise ValueError(f"cannot load the Haar cascade {path!r}")
        self.default_threshold = s.default_threshold
        self.camera = None  # set by the node/evaluation: the camera of the frames judged

    def faces(self, frame: ImageFeatures) -> np.ndarray:
        """Face boxes (N x 4: x, y, w, h) of the frame, detected once per frame."""
        faces = frame.cache.get("faces")
        if faces is None:
            s = self.settings
            found = self._cascade.detectMultiScale(
                cv2.equalizeHist(frame.grey()),
                scaleFactor=s.scale_factor,
                minNeighbors=s.min_neighbors,
                minSize=(s.min_face_px, s.min_face_px),
            )
            faces = np.asarray(found, dtype=np.float64).reshape(-1, 4)
            frame.cache["faces"] = faces
        return faces

    def _angles(self, faces: np.ndarray, camera) -> tuple[np.ndarray, np.ndarray]:
        u = faces[:, 0] + faces[:, 2] / 2
        v = faces[:, 1] + faces[:, 3] / 2
        return camera.bearing(u), camera.elevation(v)

    def learn(self, frame: ImageFeatures, rect: Rect, view: View) -> dict[str, np.ndarray]:
        cam = self._camera(frame)
        faces = self.faces(frame)
        x0, y0, x1, y1 = rect
        z, found = self.settings.face_height_m, 0.0
        if faces.shape[0] and math.isfinite(view.depth_m):
            cu = faces[:, 0] + faces[:, 2] / 2
            cv = faces[:, 1] + faces[:, 3] / 2
            inside = (cu >= x0) & (cu < x1) & (cv >= y0) & (cv < y1)
            if inside.any():
                k = int(np.argmax(np.where(inside, faces[:, 2], -1)))
                _, beta = self._angles(faces[k : k + 1], cam)
                rho = math.hypot(view.depth_m, view.lateral_m)
                z, found = cam.height_m - rho * math.tan(float(beta[0])), 1.0
        return {"face": np.array([z, found], dtype=np.float32)}

    def check_model(self, model: Model) -> None:
        """ValueError unless ``face`` is what :meth:`learn` gives: [face-centre height in
        metres, 1 if a face was seen at acquisition else 0] (float)."""
        face = model.features.get("face")
        if face is None or face.dtype.kind != "f" or face.shape != (2,):
            raise ValueError(f"'face' must be 2 floats [height_m, found], got {face!r}")
        if float(face[1]) not in (0.0, 1.0):
            raise ValueError(f"'face' found flag must be 0 or 1, got {float(face[1])}")

    def describe(self, frame: ImageFeatures, rect: Rect):
        return None  # a face height does not drift: no online update

    def distances(
        self, frame: ImageFeatures, views: Sequence[View], model: Model
    ) -> list[float | None]:
        s = self.settings
        cam = self._camera(frame)
        face = model.features.get("face")
        z_model = float(face[0]) if face is not None and face.size else s.face_height_m
        faces = self.faces(frame) if any(v.ok for v in views) else np.zeros((0, 4))
        alpha, beta = self._angles(faces, cam) if faces.shape[0] else (np.zeros(0), np.zeros(0))
        out: list[float | None] = []
        for v in views:
            if not v.ok:
                out.append(None)
                continue
            if faces.shape[0] == 0:
                out.append(s.no_face_distance)  # None by default: no evidence either way
                continue
            rho = math.hypot(v.depth_m, v.lateral_m)
            a_exp = math.atan2(v.lateral_m, v.depth_m)
            b_exp = math.atan2(cam.height_m - z_model, rho)
            m = np.hypot(
                (alpha - a_exp) / s.sigma_bearing_rad, (beta - b_exp) / s.sigma_elevation_rad
            )
            best = float(m.min()) / s.gate
            out.append(best if best <= 1.0 else s.no_face_distance)
        return out

    def _camera(self, frame: ImageFeatures):
        cam = frame.cache.get("camera") or self.camera
        if cam is None:
            raise ValueError("face verifier needs the camera (frame.cache['camera'])")
        return cam
