"""shadow_hand: smooth orientation alignment.

Intent: the rotation term 1/(|theta| + 0.1) is steep near the goal and flat far from it; cos^2(theta/2) =
<q, q*>^2 is smooth over the whole range and rewards turning the block towards the goal from any start.

obs["achieved_goal"], obs["desired_goal"] [N, 7]: block position (3) and quaternion (4).
"""

SCALE = 0.5


def compute_aux_reward(obs):
    achieved = obs["achieved_goal"][:, 3:7]
    desired = obs["desired_goal"][:, 3:7]
    # normalise: the quaternions may drift from unit length; 1e-6 keeps an all-zero input finite
    achieved = achieved / (achieved.norm(dim=-1, keepdim=True) + 1e-6)
    desired = desired / (desired.norm(dim=-1, keepdim=True) + 1e-6)
    alignment = (achieved * desired).sum(-1)
    return SCALE * alignment * alignment
