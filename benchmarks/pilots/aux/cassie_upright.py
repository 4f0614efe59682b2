"""cassie (legged_gym terms): upright pelvis.

Intent: the legged_gym Cassie reward has no orientation term, and a fall costs -200 only at the end of
the episode; a per-step bonus for an upright pelvis (gravity along the pelvis' -z axis) gives the
balance signal early. It is scaled by the control step 0.02 s like every other term.

obs["observation"] [N, 42]: columns 6:9 are gravity projected into the pelvis frame (unit vector; (0, 0, -1)
when upright).
"""

DT = 0.02  # s, the control step that scales every Cassie term
SCALE = 1.0


def compute_aux_reward(obs):
    gravity = obs["observation"][:, 6:9]
    # squared sine of the tilt: g_x^2 + g_y^2 (0 upright, 1 lying on the side)
    tilt = (gravity[:, 0] * gravity[:, 0] + gravity[:, 1] * gravity[:, 1]).clamp(0.0, 1.0)
    return SCALE * DT * (1.0 - tilt)
