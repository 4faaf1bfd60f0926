"""Why the GPU simulator starts objects 0.1 micrometre lower (lmjx.sim.gpu.SETTLE_NUDGE).

A box resting exactly on the table (zero distance, as the planner places what it observes)
slides away with a random push and spin, for 1 s, in C MuJoCo (float64) and in MuJoCo Warp
(float32, Warp's CPU device or a GPU).  Started as placed, Warp's box ends millimetres from C
MuJoCo's: its height rounds up in float32, it floats a fraction of a nanometre above the
table and misses its first contacts.  Started a little lower, the two agree to a fraction of a
micrometre.

    python3 benchmarks/float32_contact_tie.py
"""

import mujoco
import numpy as np
import warp as wp
from mujoco.mjx.third_party import mujoco_warp as mjw

XML = """<mujoco><option timestep="0.005" integrator="implicitfast"/><worldbody>
<geom name="table" type="box" size="0.85 1.1 0.2" pos="0 0 -0.2" friction="0.5 0.005 0.0001"/>
<body pos="0 0 0.025"><freejoint/>
  <geom type="box" size="0.025 0.025 0.025" mass="0.1" friction="0.5 0.005 0.0001"/></body>
</worldbody></mujoco>"""


def main() -> None:
    wp.config.log_level = wp.LOG_WARNING
    m = mujoco.MjModel.from_xml_string(XML)
    m.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_NATIVECCD  # as the GPU simulator
    rng = np.random.default_rng(0)
    worlds, steps = 8, 200
    qvel = np.zeros((worlds, m.nv))
    qvel[:, 0] = rng.uniform(0.5, 1.5, worlds)
    qvel[:, 1] = rng.uniform(-0.3, 0.3, worlds)
    qvel[:, 5] = rng.uniform(-3, 3, worlds)
    ref = []
    for w in range(worlds):
        d = mujoco.MjData(m)
        d.qvel[:] = qvel[w]
        for _ in range(steps):
            mujoco.mj_step(m, d)
        ref.append(d.qpos[:2].copy())
    device = "cuda:0" if wp.get_cuda_device_count() else "cpu"
    with wp.ScopedDevice(device):
        mw = mjw.put_model(m)
        for nudge in (0.0, 1e-7, 1e-6):
            dw = mjw.put_data(m, mujoco.MjData(m), nworld=worlds, naconmax=16 * worlds, njmax=64)
            qpos = np.repeat(mujoco.MjData(m).qpos[None], worlds, axis=0)
            qpos[:, 2] -= nudge
            dw.qpos.assign(qpos.astype(np.float32))
            dw.qvel.assign(qvel.astype(np.float32))
            for _ in range(steps):
                mjw.step(mw, dw)
            d_mm = np.hypot(*(dw.qpos.numpy()[:, :2] - np.array(ref)).T) * 1000
            print(f"started {nudge * 1e6:.1f} um lower on {device}: Warp's box ends {np.median(d_mm):.4f} mm "
                  f"(median; max {d_mm.max():.4f} mm) from C MuJoCo's")  # fmt: skip


if __name__ == "__main__":
    main()
