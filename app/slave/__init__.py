"""The paper's slave, replaced by a simulated one that touches :mod:`app.world`: the ideal
Cartesian tool (:mod:`app.slave.tool`) or a robot arm (:mod:`app.slave.arm`), each with its F/T
sensor and NTRFC, chosen in one place (:mod:`app.slave.api`).

Public API::

    from app.slave import VirtualSlave, make_slave
"""

from app.slave.api import make_slave
from app.slave.tool import VirtualSlave

__all__ = ["VirtualSlave", "make_slave"]
