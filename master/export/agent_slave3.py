"""The pythonfmu3 slave of the agent FMU for FMI 3.0: :class:`rhi.master.export.agent_fmi3.AgentSlave3`.

This file is the FMI 3.0 agent FMU's main script (``master/export/agent_fmu.py`` builds it with pythonfmu3's
builder, which finds the class naming ``Fmi3Slave`` among its bases). As the FMI 2.0 agent's script, it imports
the ``rhi`` package of the Python that loads it; its resources hold the decoder checkpoint and ``rhi_agent.json``.
"""
from __future__ import annotations

try:
    from pythonfmu3 import Fmi3Slave

    from rhi.master.export.agent_fmi3 import AgentSlave3
except ImportError as error:
    raise ImportError(f"the agent FMU needs a Python with the rhi package installed ({error})") from None


class AgentSlave(AgentSlave3, Fmi3Slave):
    """One trial of the agent through FMI 3.0 co-simulation calls."""
