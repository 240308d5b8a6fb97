"""A baseline written the way the paper's released agent works: for ``rhi bench``, and an independent oracle.

The released agent (Rood et al. 2020, adapted from PixelAI) runs ONE trial in a plain Python
loop. Each step it converts the belief from numpy to a torch tensor that requires grad, runs
the decoder forward, copies the prediction back to numpy, forms the prediction error there,
and back-propagates the error through the decoder (``output.backward(error, retain_graph=True)``)
to read the visual term of dF/dmu off the input's ``.grad``; the decoder's weights require
grad too, so the backward pass also accumulates weight gradients nobody uses. Then it updates
gamma, mu and a in numpy.

Here the environment (Unity in the paper) is this project's body, camera, stimulus and rubber
arm components, stepped directly in the master's Gauss-Seidel order without the master. The
agent itself is written out below from the paper and docs/design.md, as the released agent wrote
it, and takes NOTHING from the integrator (``rhi.components.brain``), the decoder component or the
experiment (``rhi.master.tasks.illusion``): the eq. 6 belief update, the eq. 7 action and its clip,
the eqs. 8-9 gamma (Bayes on a pair of events, the decay between them, the clamp) and the
event bookkeeping are the numpy code of :meth:`PaperStyleAgent.run`; its constants are read
straight from the configuration (``config["brain"]`` etc.); the decoder input normalisation
and the resolution weight 256^2/(H W) are written here too. Only the decoder's weights (and its
training ranges) come from the model. So it is a check on the integrator: it computes the
exact integrator's numbers (to float rounding: reverse- instead of forward-mode AD), which
tests/test_bench.py asserts, and any bug in one of the two shows as a difference.

Example::

    agent = PaperStyleAgent(model, trial, config)
    record = agent.run(50)      # {"mu": (51, 2), "gamma": (51,), ...}; agent.step_seconds
"""
from __future__ import annotations

import copy
import math
import time

import numpy as np
import torch

from rhi.components.body.camera import Camera
from rhi.components.body.kinematics import REST_POSE
from rhi.components.body.plant import ArmPlant
from rhi.components.body.rubber_arm import RubberArm
from rhi.components.stimulus import Stimulus

REFERENCE_PIXELS = 256 * 256  # Sigma_v is per pixel at the paper's 256x256 (docs/results.md, "Calibrating the visual variance")


class PaperStyleAgent:
    """One trial of the protocol, run like the released agent.

    model: the decoder g (a GenerativeModel: ``.decoder``, ``.rest_pose``, ``.half_ranges``,
        ``.resolution``; its weights are copied, never changed).
    trial: what makes the trial differ (``offset_x``, ``delay_min``, ``delay_max``, ``seed``), e.g. a
        :class:`rhi.master.config.protocol.Trial`; config: the experiment's configuration (a loaded
        ``defaults.toml``), read directly.
    weight_gradients: let the backward pass compute weight gradients too, as the released agent
        does (its decoder's parameters require grad); False computes the input gradient only.
    """

    def __init__(self, model, trial, config: dict, weight_gradients: bool = True):
        self.use_decoder(model, weight_gradients)
        self.config, self.step_size = config, config["experiment"]["step_size"]
        self.environment = [RubberArm(), Stimulus(), Camera(resolution=model.resolution), ArmPlant()]
        self.rubber_arm, self.stimulus, self.camera, self.body = self.environment
        self.setup_seconds = self.step_seconds = self.decoder_seconds = 0.0
        # The environment's settings: the trial's rubber hand and delays, the configured stimulus, camera and
        # body; the real arm starts at rest (docs/design.md).
        settings = {
            "rubber_arm": {"offset_x": trial.offset_x, "offset_y": 0.0},
            "stimulus": {**config["stimulus"], "delay_min": trial.delay_min, "delay_max": trial.delay_max,
                         "seed": trial.seed},
            "camera": config["camera"],
            "body": {**config["body"], "q0_shoulder": REST_POSE[0], "q0_elbow": REST_POSE[1]},
        }
        for component in self.environment:
            component.instantiate(1)
            for name, value in settings[component.name].items():
                component.set(name, value)
        # The agent's constants, as the released agent holds them.
        brain = config["brain"]
        self.sigma_p = float(brain["proprioceptive_variance"])
        self.gamma0 = float(brain["gamma0"])
        self.sync_sd, self.async_density = float(brain["sync_sd"]), float(brain["async_density"])
        self.decay_rate, self.action_limit = float(brain["decay_rate"]), float(brain["action_limit"])
        # The action law (a leaky integrator, time constant tau; inf: the paper's eq. 7 as released).
        self.action_time_constant = float(brain["action_time_constant"])
        if math.isfinite(float(brain["spatial_sd"])):
            raise ValueError("the paper-style baseline has the paper's causal inference over time only: "
                             "brain.spatial_sd must be inf")
        self.mu0 = np.array(REST_POSE, dtype=float)  # the belief starts where the arm rests
        # Sigma_v^-1 per pixel at this resolution: Sigma_v is given at 256 x 256.
        self.precision = REFERENCE_PIXELS / model.resolution ** 2 / config["decoder"]["visual_variance"]

    def use_decoder(self, model, weight_gradients: bool) -> None:
        """A copy of the decoder, its weights requiring grad or not, and its input normalisation."""
        self.decoder = copy.deepcopy(model.decoder).requires_grad_(weight_gradients)
        self.rest = torch.tensor(np.asarray(model.rest_pose, dtype=np.float32))
        self.half = torch.tensor(np.asarray(model.half_ranges, dtype=np.float32))

    def visual_forward(self, mu: np.ndarray):
        """numpy -> torch: the input tensor (1, 2) (requires grad) and g(mu), as the released agent's
        get_visual_forward; the decoder sees the angles scaled to [-1, 1] over its training ranges."""
        inpt = torch.tensor(np.reshape(mu, (1, 2)), dtype=torch.float32, requires_grad=True)
        return inpt, self.decoder((inpt - self.rest) / self.half)

    def visual_drive(self, inpt, output, error: np.ndarray) -> np.ndarray:
        """J^T Sigma_v^-1 e by a backward pass with grad_outputs e (retain_graph, as released), torch -> numpy."""
        inpt.grad = torch.zeros_like(inpt)
        output.backward(torch.tensor(error * self.precision, dtype=torch.float32), retain_graph=True)
        return inpt.grad.numpy()[0].astype(np.float64)

    # -- the agent's equations --------------------------------------------------------------------
    def bayes(self, gamma: float, visual_time: float, tactile_time: float) -> float:
        """Eq. 8: p(c1 | t_v, t_t) with prior gamma; p1 the normal density of the delay (sd sync_sd), p2 uniform."""
        delay = visual_time - tactile_time
        p1 = math.exp(-0.5 * (delay / self.sync_sd) ** 2) / (self.sync_sd * math.sqrt(2.0 * math.pi))
        evidence = p1 * gamma + self.async_density * (1.0 - gamma)
        return p1 * gamma / evidence if evidence > 0 else gamma

    def decay(self, gamma: float, time_now: float, tactile_time: float, dt: float) -> float:
        """Eq. 9, between events: gamma * exp(-(t - t_t)^2 dt r_decay), t_t the last touch felt (docs/design.md);
        before the first touch there is no time since touch, and gamma holds."""
        if not math.isfinite(tactile_time):
            return gamma
        return gamma * math.exp(-(time_now - tactile_time) ** 2 * dt * self.decay_rate)

    def run(self, steps: int) -> dict[str, np.ndarray]:
        """Run ``steps`` steps; returns mu (steps+1, 2), action, gamma, drive, body angles, force per step."""
        started = time.perf_counter()
        rubber_arm, stimulus, camera, body = self.environment
        for component in self.environment:
            component.setup_experiment(0.0, steps * self.step_size)
            component.enter_initialization_mode()
        rubber_arm.exit_initialization_mode()
        stimulus.set("target", rubber_arm.values["hand"])
        stimulus.exit_initialization_mode()
        camera.set("arm_pose", rubber_arm.values["pose"])
        camera.set("ball", stimulus.values["ball"])
        camera.exit_initialization_mode()
        body.exit_initialization_mode()

        mu, action, gamma = self.mu0.copy(), np.zeros(2), self.gamma0
        # Event bookkeeping: the event times last seen, and whether a new visual / tactile event came since the
        # last Bayes update (the released agent's flags).
        seen_visual = seen_tactile = -math.inf
        new_visual = new_tactile = False
        record = {"mu": [mu.copy()], "action": [action.copy()], "gamma": [gamma], "drive": [np.zeros(2)],
                  "q": [np.array([body.values["q_shoulder"][0], body.values["q_elbow"][0]])],
                  "force_x": [body.values["force_x"][0]]}
        stepping = time.perf_counter()
        self.setup_seconds = stepping - started
        for tick in range(steps):
            t, h = tick * self.step_size, self.step_size
            # The environment advances (the rubber arm is still; the ball moves; the camera sees it).
            rubber_arm.do_step(t, h)
            stimulus.set("target", rubber_arm.values["hand"])
            stimulus.do_step(t, h)
            camera.set("arm_pose", rubber_arm.values["pose"])
            camera.set("ball", stimulus.values["ball"])
            camera.do_step(t, h)
            s_v = camera.values["image"][0]
            s_p = np.array([body.values["q_shoulder"][0], body.values["q_elbow"][0]])

            # Gamma (eqs. 8-9): Bayes once a new visual and a new tactile event were both seen, else the decay.
            # The stimulus has already advanced to t + h (Gauss-Seidel), so the decay measures from t + h.
            visual_time = float(stimulus.values["visual_time"][0])
            tactile_time = float(stimulus.values["tactile_time"][0])
            new_visual |= visual_time != seen_visual and math.isfinite(visual_time)
            new_tactile |= tactile_time != seen_tactile and math.isfinite(tactile_time)
            seen_visual, seen_tactile = visual_time, tactile_time
            if new_visual and new_tactile:
                gamma = self.bayes(gamma, visual_time, tactile_time)
                new_visual = new_tactile = False
            else:
                gamma = self.decay(gamma, t + h, tactile_time, h)
            gamma = min(max(gamma, self.gamma0), 1.0)

            # The released agent's active_inference_step: forward, error in numpy, backward, Euler.
            began = time.perf_counter()
            inpt, output = self.visual_forward(mu)
            g_mu = output.detach().numpy()
            drive = self.visual_drive(inpt, output, s_v[None] - g_mu)
            self.decoder_seconds += time.perf_counter() - began
            mu_dot = (s_p - mu) / self.sigma_p + gamma * drive          # eq. 6
            mu = mu + h * mu_dot
            a_dot = -(s_p - mu) / self.sigma_p                          # eq. 7, with the updated belief
            tau = self.action_time_constant
            leak = 0.0 if math.isinf(tau) else action / tau   # a <- a + h (a_dot - a / tau), then the clip
            action = np.clip(action + h * (a_dot - leak), -self.action_limit, self.action_limit)

            body.set("u_shoulder", action[:1].copy())
            body.set("u_elbow", action[1:].copy())
            body.do_step(t, h)
            for key, value in (("mu", mu), ("action", action), ("gamma", gamma), ("drive", drive),
                               ("q", np.array([body.values["q_shoulder"][0], body.values["q_elbow"][0]])),
                               ("force_x", body.values["force_x"][0])):
                record[key].append(np.array(value, copy=True))
        self.step_seconds = time.perf_counter() - stepping
        for component in self.environment:
            component.terminate()
        return {key: np.array(rows) for key, rows in record.items()}
