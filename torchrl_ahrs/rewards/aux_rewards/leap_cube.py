"""leap_cube (MuJoCo Playground LEAP cube reorientation): calm finger commands.

Intent: the cube falls out of the palm when the fingers make large, jerky moves; a small penalty on the
squared action (position targets around the default pose) keeps the finger motion moderate while the
orientation terms drive the rotation. Scaled by ctrl_dt 0.05 s like the task's terms.

obs["action"] [N, 16]: the finger commands in [-1, 1].
"""

DT = 0.05  # s
SCALE = 0.1


def compute_aux_reward(obs):
    action = obs["action"]
    return -SCALE * DT * (action * action).mean(-1)
