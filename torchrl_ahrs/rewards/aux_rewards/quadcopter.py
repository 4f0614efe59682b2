"""quadcopter: velocity towards the target, slowing down on arrival.

Intent: pos = 1/(1+d^2) is nearly flat far from the target; rewarding the velocity along the direction
to the target (clipped at 1 m/s and faded within 0.5 m so the copter brakes and hovers) gives a gradient
from every starting point.

obs["observation"] [N, 13] = target - position (3), orientation quaternion (4), linear velocity / 2 (3),
angular velocity / pi (3).
"""

SCALE = 0.3  # a fraction of the pos term's maximum of 1
BRAKE_RADIUS = 0.5  # m


def compute_aux_reward(obs):
    observation = obs["observation"]
    to_target = observation[:, 0:3]
    velocity = observation[:, 7:10] * 2.0  # undo the observation scale
    distance = to_target.norm(dim=-1)
    direction = to_target / (distance.unsqueeze(-1) + 1e-6)
    approach_speed = (velocity * direction).sum(-1).clamp(-1.0, 1.0)
    fade = (distance / BRAKE_RADIUS).clamp(0.0, 1.0)
    return SCALE * approach_speed * fade
