"""The body FMU contract: the ports any body plant must have to take the arm's place (docs/design.md,
"Body FMU contract"). The native plant (:mod:`rhi.components.body.plant`) declares them; an FMU swapped in with
``--body`` is checked against them before anything runs. :data:`FMI3_ARRAYS`: the same ports as the body FMUs'
FMI 3.0 builds carry them (docs/fmi.md)."""
from ..variables import ContractVariable

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

# The FMI 3.0 form of the contract's pairs, one Float64 array each, as every FMI 3.0 body build declares them (the
# C body, master/export/c_body.py; the pythonfmu3 ones, components/fmi_export/slave_fmi3.py; written by
# components/fmi_export/description_fmi3.py): name -> (description, the FMI 2.0 ports it carries, in order).
FMI3_ARRAYS = {
    "u": ("commanded joint velocities a: shoulder, elbow", ("u_shoulder", "u_elbow")),
    "q": ("joint angles (proprioception s_p): shoulder from +x, elbow relative to the upper arm",
          ("q_shoulder", "q_elbow")),
    "hand": ("hand position: x right of the body midline, y forward of the shoulder line", ("hand_x", "hand_y")),
    "force": ("force the held arm exerts at the hand: x, y (0 when free)", ("force_x", "force_y")),
}
