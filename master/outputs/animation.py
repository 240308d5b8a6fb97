"""An animated GIF of one trial: the rubber arm and the ball as the agent sees them, and the
perceived arm (the forward model of mu) in red, drifting toward the rubber arm."""
from __future__ import annotations

import io

import numpy as np
from PIL import Image

from rhi.components.body import kinematics
from rhi.components.body.camera import render


def frames(mu: np.ndarray, rubber_pose, balls: np.ndarray, resolution: int, every: int = 10,
           scale: int | None = None):
    """RGB frames: gray = what the camera shows (rubber arm, ball); red = the perceived arm; every nth step,
    enlarged ``scale`` times (default: 3 up to 64 px, else 1; large frames make a big GIF, slow to write)."""
    scale = scale or (3 if resolution <= 64 else 1)
    chosen = np.arange(0, len(mu), every)
    seen = render(np.repeat(np.asarray(rubber_pose, float)[None], len(chosen), 0), resolution, balls[chosen])
    perceived = render(mu[chosen], resolution, None)
    real = render(np.repeat(np.asarray(kinematics.REST_POSE, float)[None], 1, 0), resolution, None)[0]
    images = []
    for gray, red in zip(seen, perceived):
        rgb = np.stack([np.maximum(gray, red), gray, np.maximum(gray, 0.35 * real)], axis=-1)
        image = Image.fromarray((255 * np.clip(rgb, 0, 1)).astype(np.uint8), "RGB")
        images.append(image.resize((resolution * scale, resolution * scale), Image.NEAREST))
    return images


def gif_bytes(images, milliseconds: int = 80) -> bytes:
    """The PIL ``images`` as an animated GIF, ``milliseconds`` per frame, looping forever."""
    buffer = io.BytesIO()
    images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:], duration=milliseconds, loop=0)
    return buffer.getvalue()
