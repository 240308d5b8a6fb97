"""The body FMU contract: the ports any body plant must have to take the arm's place (docs/design.md,
"Body FMU contract"). The native plant (:mod:`components.body.plant`) declares them; an FMU swapped in with
``--body`` is checked against them before anything runs."""
from components.variables import ContractVariable

BODY_CONTRACT = (
    ContractVariable("u_shoulder", "input", "Real", "deg/s"),
    ContractVariable("u_elbow", "input", "Real", "deg/s"),
    ContractVariable("q_shoulder", "output", "Real", "deg"),
    ContractVariable("q_elbow", "output", "Real", "deg"),
    ContractVariable("hand_x", "output", "Real", "m"),
    ContractVariable("hand_y", "output", "Real", "m"),
    ContractVariable("force_x", "output", "Real", "N"),
    ContractVariable("force_y", "output", "Real", "N"),
    ContractVariable("held", "parameter", "Boolean"),
    ContractVariable("q0_shoulder", "parameter", "Real", "deg"),
    ContractVariable("q0_elbow", "parameter", "Real", "deg"),
)
