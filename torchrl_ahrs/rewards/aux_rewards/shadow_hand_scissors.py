"""shadow_hand_scissors: handle separation without the grasp gate.

Intent: the open term pays nothing until both hands have all fingertips near their handles (summed
distance < 0.7 m each), so early on the policy gets no signal for opening; the distance between the two
handle rings (0.09 m when closed) grows as the scissors open however the hands hold them, and gives that
signal from the start. Capped at 0.3 m of extra separation.

obs["observation"] [N, 210]: right hand (95), left hand (95), scissors pose (7), linear velocity (3),
angular velocity x 0.2 (3), right handle position (3, at 203), left handle position (3, at 206), joint (1).
"""

SCALE = 3.0  # at most 0.9, below the open term's 5 x 1.2
CLOSED_SEPARATION = 0.09  # m, between the ring centres of the closed scissors


def compute_aux_reward(obs):
    observation = obs["observation"]
    separation = (observation[:, 203:206] - observation[:, 206:209]).norm(dim=-1)
    return SCALE * (separation - CLOSED_SEPARATION).clamp(0.0, 0.3)
