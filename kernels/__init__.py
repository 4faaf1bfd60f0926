"""lmjx's batched kernels: pure functions of arrays (kinematics, collision, IK).

Shipped inside the package as `kernels`.  No I/O and no jit here: callers jit and
vmap at their entry points (see `lmjx.ik_batch`).
"""
