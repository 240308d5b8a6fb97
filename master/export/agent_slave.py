"""The pythonfmu slave of the agent FMU: :class:`rhi.master.export.agent.Agent` behind the FMI 2.0 co-simulation API.

This file is the agent FMU's main script (``master/export/agent_fmu.py`` builds it). Unlike the body
FMU, it carries no copy of the code: it imports the ``rhi`` package (``master``, ``components``) of
the Python that loads it, which must have rhi and its dependencies (torch, ...) installed. Its
resources hold the decoder checkpoint and ``rhi_agent.json``: the task (the illusion's agent or the
reach's), the decoder's kind, the configuration it was built with and the ports it declared; a package whose agent declares other ports is refused
when the FMU is instantiated. One FMU instance is one trial (batch size 1); the slave base,
:class:`rhi.components.fmi_export.slave_fmi2.ComponentSlaveBase`, registers the variables and runs the lifecycle.
pythonfmu takes the class of this file that has ``Fmi2Slave`` deepest among its bases.
"""
from __future__ import annotations

try:
    from rhi.components.fmi_export.slave_fmi2 import ComponentSlaveBase
    from rhi.components.model_description import xml_value
    from rhi.master.export.agent_fmu import agent_from_resources
except ImportError as error:
    raise ImportError(f"the agent FMU needs a Python with the rhi package installed ({error})") from None


class AgentSlave(ComponentSlaveBase):
    """One trial of the agent (the illusion's or the reach's), driven through FMI 2.0 co-simulation calls."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        agent, self.modelName, self.description = agent_from_resources(self.resources)
        self.author, self.license = "rhi", "MIT"
        self.serve(agent)

    def start_text(self, variable, written):
        """A parameter's or input's start as the agent declares it."""
        if variable.causality in ("parameter", "input"):
            return xml_value(variable.start if variable.type != "Real" else float(variable.start))
        return written
