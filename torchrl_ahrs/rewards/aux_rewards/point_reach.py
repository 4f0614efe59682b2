"""point_reach: velocity towards the target.

Intent: the native reward pays -distance and an arrival bonus, which says where to be but not which
way to move; rewarding the velocity component along the direction to the target gives a signal from the
first step. It fades inside 0.2 m so the point mass settles instead of overshooting.

obs["observation"] [N, 6] = position (2), velocity (2), target - position (2).
"""

SCALE = 0.5  # comparable to the -distance term (~ -1 per step at the start)
SETTLE_RADIUS = 0.2  # m: below this the push towards the target fades out


def compute_aux_reward(obs):
    observation = obs["observation"]
    velocity = observation[:, 2:4]
    to_target = observation[:, 4:6]
    distance = to_target.norm(dim=-1)
    # unit direction to the target; the 1e-6 keeps it finite when the point sits on the target
    direction = to_target / (distance.unsqueeze(-1) + 1e-6)
    # speed along that direction, clipped so a fast pass-through is not over-paid
    approach_speed = (velocity * direction).sum(-1).clamp(-1.0, 1.0)
    # 0 on the target, 1 beyond the settle radius
    fade = (distance / SETTLE_RADIUS).clamp(0.0, 1.0)
    return SCALE * approach_speed * fade
