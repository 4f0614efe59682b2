"""go1_terrain (MuJoCo Playground Go1 joystick terms): level body.

Intent: on rough terrain the robot falls when its body rolls or pitches; a smooth bonus for a level body
(gravity along the body's -z axis) complements the command-tracking terms. Scaled by ctrl_dt 0.02 s like
the task's terms.

obs["observation"] [N, 48]: columns 6:9 are gravity in the body frame ((0, 0, -1) when level).
"""

import torch

DT = 0.02  # s
SCALE = 1.0


def compute_aux_reward(obs):
    gravity = obs["observation"][:, 6:9]
    tilt = (gravity[:, 0] * gravity[:, 0] + gravity[:, 1] * gravity[:, 1]).clamp(0.0, 1.0)
    # exp(-tilt / 0.1): 1 level, ~0.37 at an 18-degree tilt
    return SCALE * DT * torch.exp(-tilt / 0.1)
