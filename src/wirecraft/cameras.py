"""Camera settings of a cell, matched to a real one, and sensor-style noise on rendered RGB.

A ``CameraConfig`` holds what differs between cells: the side camera's pose (eye and target)
and field of view, the wrist camera's field of view, the far clip, an exposure gain and an
``ImageNoise``.  It loads from a TOML file (one per cell)::

    [side]
    pos = [0.6, -0.65, 0.76]      # m, world
    target = [0.0, -0.05, 0.05]   # m, world: the point it looks at
    fovy = 50.0                   # deg, vertical field of view
    [wrist]
    fovy = 70.0
    [image]
    far_clip = 3.0                # m
    exposure_gain = 1.2           # multiplies the rendered RGB
    [noise]
    shot = 0.01                   # Poisson-like: std = sqrt(shot * I) at intensity I in [0, 1]
    read = 0.005                  # std of additive Gaussian read noise (fraction of full scale)
    colour_shift = 0.03           # per-channel gain drawn once per episode, 1 +/- this (uniform)
    blur = 0.6                    # px, std of a Gaussian blur
    jpeg_quality = 80             # 1-100: JPEG-compressed and decoded again; 0: none

``wirecraft.make(..., camera_config=CONFIG | dict | "cell.toml")`` builds the cameras from it and
post-processes every rendered RGB image (observations and dataset frames alike) with
``postprocess``; ``wirecraft collect --camera-config cell.toml`` records with it.  The noise of
an image depends only on the episode's reset seed, the control step and the camera, so an
episode's images are reproducible whatever else was rendered.
"""

from __future__ import annotations

import dataclasses
import io
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wirecraft import validation

OWNER = "CameraConfig"


def _vector(owner: str, name: str, value) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} must be 3 numbers, got {value!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{owner}.{name} must be 3 finite numbers, got {value!r}")
    return values


@dataclass(frozen=True)
class ImageNoise:
    shot: float = 0.0
    read: float = 0.0
    colour_shift: float = 0.0
    blur: float = 0.0  # px
    jpeg_quality: int = 0  # 0: no JPEG round trip

    def __post_init__(self) -> None:
        owner = "ImageNoise"
        for name in ("shot", "read", "colour_shift", "blur"):
            validation.non_negative(owner, name, getattr(self, name))
        if self.colour_shift >= 1.0:
            raise ValueError(f"{owner}.colour_shift must be < 1, got {self.colour_shift!r}")
        validation.int_in_range(owner, "jpeg_quality", self.jpeg_quality, 0, 100)

    @property
    def active(self) -> bool:
        return bool(self.shot or self.read or self.colour_shift or self.blur or self.jpeg_quality)

    def apply(self, rgb: np.ndarray, rng: np.random.Generator, colour: np.ndarray) -> np.ndarray:
        """``rgb`` (H, W, 3) uint8 with the noise drawn from ``rng``; ``colour`` (3,) the
        episode's per-channel gains."""
        image = rgb.astype(np.float64) / 255.0 * colour
        if self.shot:
            image = image + np.sqrt(self.shot * np.clip(image, 0.0, None)) * rng.standard_normal(
                image.shape
            )
        if self.read:
            image = image + self.read * rng.standard_normal(image.shape)
        out = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
        if self.blur or self.jpeg_quality:
            from PIL import Image, ImageFilter

            picture = Image.fromarray(out)
            if self.blur:
                picture = picture.filter(ImageFilter.GaussianBlur(self.blur))
            if self.jpeg_quality:
                buffer = io.BytesIO()
                picture.save(buffer, format="JPEG", quality=self.jpeg_quality)
                picture = Image.open(io.BytesIO(buffer.getvalue()))
            out = np.asarray(picture.convert("RGB"), dtype=np.uint8)
        return out


@dataclass(frozen=True)
class CameraConfig:
    side_pos: tuple[float, float, float] | None = None  # None: the built-in side camera
    side_target: tuple[float, float, float] | None = None
    side_fovy: float | None = None  # deg
    wrist_fovy: float | None = None  # deg
    far_clip: float | None = None  # m
    exposure_gain: float = 1.0
    noise: ImageNoise = field(default_factory=ImageNoise)

    def __post_init__(self) -> None:
        if (self.side_pos is None) != (self.side_target is None):
            raise ValueError(f"{OWNER}: give the side camera's pos and target together")
        for name in ("side_pos", "side_target"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _vector(OWNER, name, getattr(self, name)))
        for name in ("side_fovy", "wrist_fovy"):
            value = getattr(self, name)
            if value is not None:
                validation.in_range(OWNER, name, value, 1.0, 179.0)
        if self.far_clip is not None:
            validation.positive(OWNER, "far_clip", self.far_clip)
        validation.positive(OWNER, "exposure_gain", self.exposure_gain)
        if isinstance(self.noise, dict):
            object.__setattr__(self, "noise", ImageNoise(**self.noise))
        if not isinstance(self.noise, ImageNoise):
            raise ValueError(f"{OWNER}.noise must be an ImageNoise or a table, got {self.noise!r}")

    # -- files and records -----------------------------------------------------------------
    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> CameraConfig:
        """From the TOML layout (``side``, ``wrist``, ``image``, ``noise`` tables) or the flat
        ``as_dict`` one; an unknown key is a ValueError naming it."""
        values = validation.mapping(OWNER, "config", values)
        if not set(values) & {"side", "wrist", "image"}:
            known = {f.name for f in dataclasses.fields(cls)}
            unknown = sorted(set(values) - known)
            if unknown:
                raise ValueError(f"{OWNER}: unknown key {unknown[0]!r}; valid: {sorted(known)}")
            return cls(**values)
        tables = {"side": ("pos", "target", "fovy"), "wrist": ("fovy",)}
        tables["image"] = ("far_clip", "exposure_gain")
        tables["noise"] = tuple(f.name for f in dataclasses.fields(ImageNoise))
        flat: dict[str, Any] = {}
        for table, value in values.items():
            if table not in tables:
                raise ValueError(f"{OWNER}: unknown table [{table}]; valid: {sorted(tables)}")
            value = validation.mapping(OWNER, f"[{table}]", value)
            for key in value:
                if key not in tables[table]:
                    raise ValueError(
                        f"{OWNER}: unknown key {key!r} in [{table}]; valid: {list(tables[table])}"
                    )
            if table == "noise":
                flat["noise"] = dict(value)
            elif table == "image":
                flat.update(value)
            else:
                flat.update({f"{table}_{k}": v for k, v in value.items()})
        return cls(**flat)

    @classmethod
    def load(cls, path: str | Path) -> CameraConfig:
        path = Path(path)
        try:
            values = tomllib.loads(path.read_text())
        except OSError as err:
            raise ValueError(f"cannot read the camera config {path}: {err}") from None
        except tomllib.TOMLDecodeError as err:
            raise ValueError(f"{path} is not valid TOML: {err}") from None
        try:
            return cls.from_dict(values)
        except (ValueError, TypeError) as err:
            raise ValueError(f"{path}: {err}") from None

    @classmethod
    def of(cls, value) -> CameraConfig | None:
        """A config from a ``CameraConfig``, a dict (``as_dict`` or TOML layout), a TOML path,
        or None."""
        if value is None or isinstance(value, cls):
            return value
        if isinstance(value, dict):
            return cls.from_dict(value)
        if isinstance(value, (str, Path)):
            return cls.load(value)
        raise ValueError(f"camera_config must be a CameraConfig, a dict or a path, got {value!r}")

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    # -- the model -------------------------------------------------------------------------
    def apply_to_spec(self, spec, side_camera: str | None, wrist_camera: str) -> None:
        """Set the cameras of ``spec`` (before compiling)."""
        from wirecraft.assets.robots.grippers import _look_at_quat

        if side_camera is not None:
            side = spec.camera(side_camera)
            if self.side_pos is not None:
                eye, target = np.array(self.side_pos), np.array(self.side_target)
                side.pos = eye
                side.quat = _look_at_quat(eye, target, np.array([0.0, 0.0, 1.0]))
            if self.side_fovy is not None:
                side.fovy = self.side_fovy
        if self.wrist_fovy is not None:
            spec.camera(wrist_camera).fovy = self.wrist_fovy

    def apply_to_model(self, model) -> None:
        """Set the far clip (MuJoCo keeps it relative to the model's extent)."""
        if self.far_clip is not None:
            model.vis.map.zfar = self.far_clip / model.stat.extent

    # -- images ----------------------------------------------------------------------------
    @property
    def changes_images(self) -> bool:
        return self.exposure_gain != 1.0 or self.noise.active

    def episode_colour(self, episode_seed: int) -> np.ndarray:
        """(3,) per-channel gains of an episode: exposure gain times the colour shift."""
        rng = np.random.default_rng([episode_seed, 0xC01])
        shift = rng.uniform(-self.noise.colour_shift, self.noise.colour_shift, 3)
        return self.exposure_gain * (1.0 + shift)

    def postprocess(self, rgb: np.ndarray, episode_seed: int, step: int, camera: int):
        """The image a real sensor would give of ``rgb``: gain, colour shift, noise, blur,
        JPEG.  Its random draws depend only on (episode seed, control step, camera index)."""
        if not self.changes_images:
            return rgb
        rng = np.random.default_rng([episode_seed, step, camera])
        return self.noise.apply(rgb, rng, self.episode_colour(episode_seed))


class SensorNoiseTransform:
    """``ImageNoise`` as a dataset image transform: a callable on a (C, H, W) float tensor in
    [0, 1] (what ``LeRobotDataset`` yields), e.g. ``LeRobotDataset(repo_id, root=DIR,
    image_transforms=SensorNoiseTransform(ImageNoise(read=0.01), seed=0))``.  Each call draws
    from the transform's own generator (seeded), with a colour shift per call."""

    def __init__(self, noise: ImageNoise, seed: int = 0) -> None:
        if not isinstance(noise, ImageNoise):
            raise ValueError(f"SensorNoiseTransform needs an ImageNoise, got {noise!r}")
        self.noise = noise
        self.rng = np.random.default_rng(seed)

    def __call__(self, image):
        import torch

        array = image.detach().cpu().numpy()
        rgb = np.clip(np.rint(np.moveaxis(array, 0, -1) * 255.0), 0, 255).astype(np.uint8)
        shift = self.noise.colour_shift
        colour = 1.0 + self.rng.uniform(-shift, shift, 3)
        noisy = self.noise.apply(rgb, self.rng, colour)
        out = torch.from_numpy(np.moveaxis(noisy, -1, 0).astype(np.float32) / 255.0)
        return out.to(dtype=image.dtype, device=image.device)
