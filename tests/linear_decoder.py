"""A toy decoder with the visual decoder's outputs: g(mu) = A mu + b, a fixed seen image s_v.

visual_drive = A^T (s_v - g(mu)) / Sigma_v, visual_error = |s_v - g(mu)|^2 / (2 Sigma_v),
visual_stiffness = largest eigenvalue of A^T A / Sigma_v: the Jacobian of g is A exactly, so
the fixed point of the brain with this decoder has a closed form.
"""
import numpy as np

from rhi.components.component import Component
from rhi.components.variables import Variable


class LinearDecoder(Component):
    """g(mu) = A mu + b on a flat 'image' of ``len(b)`` pixels, the seen image a parameter."""

    def __init__(self, A, b, seen, name="decoder"):
        self.A, pixels = np.asarray(A, float), len(b)
        feed = dict(causality="output", depends_on=("mu",))
        super().__init__(name, [
            Variable("offset", "parameter", "Array", shape=(pixels,), start=np.asarray(b, float), unit="1",
                     description="b"),
            Variable("seen", "parameter", "Array", shape=(pixels,), start=np.asarray(seen, float), unit="1",
                     description="the fixed seen image s_v"),
            Variable("visual_variance", "parameter", start=1.0, unit="1", min=0.0, description="Sigma_v"),
            Variable("mu", "input", "Array", shape=(2,), start=0.0, unit="deg", description="belief"),
            Variable("visual_drive", type="Array", shape=(2,), unit="deg/s", **feed, description="A^T e / Sigma_v"),
            Variable("prediction", type="Array", shape=(pixels,), unit="1", **feed, description="A mu + b"),
            Variable("visual_error", unit="1", **feed, description="|e|^2 / (2 Sigma_v)"),
            Variable("visual_stiffness", unit="1/s", **feed, description="max eig(A^T A) / Sigma_v"),
        ])

    def initialize(self):
        self.step(0.0, 0.0)

    def step(self, t, h):
        variance = self.values["visual_variance"]
        prediction = self.values["mu"] @ self.A.T + self.values["offset"]
        error = self.values["seen"] - prediction
        self.values["prediction"] = prediction
        self.values["visual_drive"] = error @ self.A / variance[:, None]
        self.values["visual_error"] = (error ** 2).sum(axis=1) / (2.0 * variance)
        self.values["visual_stiffness"] = np.linalg.eigvalsh(self.A.T @ self.A).max() / variance
