"""A baseline written the way the paper's released agent works, for ``rhi bench`` to compare against.

The released agent (Rood et al. 2020, adapted from PixelAI) runs ONE trial in a plain Python
loop. Each step it converts the belief from numpy to a torch tensor that requires grad, runs
the decoder forward, copies the prediction back to numpy, forms the prediction error there,
and back-propagates the error through the decoder (``output.backward(error, retain_graph=True)``)
to read the visual term of dF/dmu off the input's ``.grad``; the decoder's weights require
grad too, so the backward pass also accumulates weight gradients nobody uses. Then it updates
gamma, mu and a in numpy.

Here the environment (Unity in the paper) is this project's body, camera, stimulus and rubber
arm components, stepped directly in the master's Gauss-Seidel order without the master, and
the brain's equations and its event bookkeeping are the brain's own functions (``observe_events``,
``update_gamma``, ``euler_step``): only the data flow is the released agent's. So the baseline
computes the same numbers as the exact integrator (to float rounding: reverse- instead of
forward-mode AD).

Example::

    agent = PaperStyleAgent(model, trial, config)
    record = agent.run(50)      # {"mu": (51, 2), "gamma": (51,), ...}; agent.step_seconds
"""
from __future__ import annotations

import copy
import time

import numpy as np
import torch

from components.body.camera import Camera
from components.body.plant import ArmPlant
from components.body.rubber_arm import RubberArm
from components.brain.causal_inference import observe_events, update_gamma
from components.brain.integrator import Brain, euler_step
from components.stimulus import Stimulus
from components.vision.component import GenerativeModel, resolution_weight
from components.vision.networks import normalise
from master.experiment import Trial, parameters


class PaperStyleAgent:
    """One trial of the protocol, run like the released agent.

    model: the decoder g (a GenerativeModel; its weights are copied, never changed).
    trial, config: as for :func:`master.experiment.run_batch` (one trial).
    weight_gradients: let the backward pass compute weight gradients too, as the released agent
        does (its decoder's parameters require grad); False computes the input gradient only.
    """

    def __init__(self, model: GenerativeModel, trial: Trial, config: dict, weight_gradients: bool = True):
        self.use_decoder(model, weight_gradients)
        self.config, self.step_size = config, config["experiment"]["step_size"]
        self.environment = [RubberArm(), Stimulus(), Camera(resolution=model.resolution), ArmPlant()]
        self.rubber_arm, self.stimulus, self.camera, self.body = self.environment
        self.setup_seconds = self.step_seconds = self.decoder_seconds = 0.0
        given = parameters([trial], config)
        for component in self.environment:
            component.instantiate(1)
            for path, value in given.items():
                name, _, variable = path.partition(".")
                if name == component.name:
                    component.set(variable, value)
        brain = config["brain"]
        self.sigma_p, self.gamma0 = brain["proprioceptive_variance"], brain["gamma0"]
        self.brain, self.mu0 = brain, np.array(given["brain.mu0"], dtype=float)
        # The experiment leaves the action limit at the brain component's start value.
        self.action_limit = float(given.get("brain.action_limit", Brain().variables["action_limit"].start))
        self.action_time_constant = float(given["brain.action_time_constant"])
        self.precision = resolution_weight(model.resolution, model.resolution) / config["decoder"]["visual_variance"]

    def use_decoder(self, model: GenerativeModel, weight_gradients: bool) -> None:
        """A copy of the decoder, its weights requiring grad or not, and the input normalisation."""
        self.decoder = copy.deepcopy(model.decoder).requires_grad_(weight_gradients)
        self.rest = torch.tensor(model.rest_pose, dtype=torch.float32)
        self.half = torch.tensor(model.half_ranges, dtype=torch.float32)

    def visual_forward(self, mu: np.ndarray):
        """numpy -> torch: the input tensor (requires grad) and g(mu), as the released agent's get_visual_forward."""
        inpt = torch.tensor(mu, dtype=torch.float32, requires_grad=True)
        return inpt, self.decoder(normalise(inpt, self.rest, self.half))

    def visual_drive(self, inpt, output, error: np.ndarray) -> np.ndarray:
        """J^T Sigma_v^-1 e by a backward pass with grad_outputs e (retain_graph, as released), torch -> numpy."""
        inpt.grad = torch.zeros_like(inpt)
        output.backward(torch.tensor(error * self.precision, dtype=torch.float32), retain_graph=True)
        return inpt.grad.numpy().astype(np.float64)

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

        mu, action, gamma = self.mu0[None].copy(), np.zeros((1, 2)), np.array([self.gamma0], float)
        events = (np.array([-np.inf]), np.array([-np.inf]), np.array([False]), np.array([False]))
        variance, limit = np.array([self.sigma_p], float), np.array([self.action_limit])
        time_constant = np.array([self.action_time_constant])
        record = {"mu": [mu[0].copy()], "action": [action[0].copy()], "gamma": [gamma[0]], "drive": [np.zeros(2)],
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
            s_p = np.stack([body.values["q_shoulder"], body.values["q_elbow"]], axis=1)

            # Gamma from the touch events: Bayes once a new visual and a new tactile event were seen.
            visual_time, tactile_time = stimulus.values["visual_time"], stimulus.values["tactile_time"]
            pair, *events = observe_events(*events, visual_time, tactile_time)
            gamma = update_gamma(gamma, pair, visual_time, tactile_time, t + h, h, self.gamma0,
                                 self.brain["sync_sd"], self.brain["async_density"], self.brain["decay_rate"])

            # The released agent's active_inference_step: forward, error in numpy, backward, Euler.
            began = time.perf_counter()
            inpt, output = self.visual_forward(mu)
            g_mu = output.detach().numpy()
            drive = self.visual_drive(inpt, output, s_v[None] - g_mu)
            self.decoder_seconds += time.perf_counter() - began
            mu, _, action = euler_step(mu, action, s_p, gamma, drive, variance, limit, h, time_constant)

            body.set("u_shoulder", action[:, 0].copy())
            body.set("u_elbow", action[:, 1].copy())
            body.do_step(t, h)
            for key, value in (("mu", mu[0]), ("action", action[0]), ("gamma", gamma[0]), ("drive", drive[0]),
                               ("q", np.array([body.values["q_shoulder"][0], body.values["q_elbow"][0]])),
                               ("force_x", body.values["force_x"][0])):
                record[key].append(np.array(value, copy=True))
        self.step_seconds = time.perf_counter() - stepping
        for component in self.environment:
            component.terminate()
        return {key: np.array(rows) for key, rows in record.items()}
