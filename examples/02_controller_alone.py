"""The Cartesian controller alone: joint angles and a fixed F/T reading in, motor counts out.

No plant and no world: this is what a driver for a real hand controller would call every servo
period. The Kraft-like device sits at its home pose, the deadman and reflection switches are on,
and the slave's wrist sensor reads a constant 4 N push along z (plus the payload weight, which the
controller removes). The rendered wrench ramps in over the safety ramp (0.2 s by default) after
reflection starts; the output shows each stage of the paper's Fig. 3 once it is at full strength.

    .venv/bin/python examples/02_controller_alone.py
"""

import numpy as np

from app.controller.frhc import FRHCController
from app.controller.types import FTReading, Switches
from app.device.spec import load_device
from app.slave.tool import VirtualSlave
from app.world.scene import load_scene

device = load_device("kraft")
slave_model = VirtualSlave(load_scene("probe")).slave_model()  # payload mass, sensor frame
controller = FRHCController(device, device.data.gains, slave_model)

q = np.array(device.data.home)  # encoder angles (rad)
weight_S = slave_model.payload_mass * slave_model.gravity_w  # the sensor's {S} is aligned with {w} at home
reading = FTReading(wrench_S=np.array([0.0, 0.0, 4.0, 0.0, 0.0, 0.0]) + np.r_[weight_S, 0.0, 0.0, 0.0])
switches = Switches(deadman=True, reflection=True)

for tick in range(300):  # 0.3 s at 1 kHz: past the ramp
    out = controller.step(q, switches, reading, dt=1e-3)
    if tick in (0, 99):
        print(f"tick {tick + 1:3d}: ramp {out.ramp:.2f}, tau_T {out.tau_T.round(4)}")

np.set_printoptions(precision=4, suppress=True)
print("faults:            ", out.faults.name, f" ramp {out.ramp:.2f}")
print("F_S_task (N, N m): ", out.F_S_task, " <- the reading with the payload weight removed")
print("F_MRF:             ", out.F_MRF, " <- moved to the tool frame (Eq 6)")
print("G_F_T:             ", out.G_F_T, " <- K_T F_MRF, to be felt at the grip")
print("tau_T (N m):       ", out.tau_T, " <- J^T F (Eq 7)")
print("tau_G (N m):       ", out.tau_G, " <- gravity compensation")
print("tau_sat (N m):     ", out.tau_sat, f" <- saturation scale {out.saturation_scale:.3f}")
print("counts:            ", out.counts)
