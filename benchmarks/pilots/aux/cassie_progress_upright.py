"""cassie (legged_gym terms), hand-written candidate: progress along the planar command, paid while upright.

Intent: as the shipped torchrl_ahrs/rewards/aux_rewards/cassie.py, the share of the commanded planar speed achieved
along the command's direction, clamped to [0, 1], so that a run that stands or turns on the spot has a reason to
step; here multiplied by the pelvis' uprightness 1 - sin^2(tilt) (1 upright, 0 lying on the side), so progress
bought by leaning into a fall is paid less. Zero when the planar command is zero. Scaled by the control step 0.02 s
like every other Cassie term: at most 20 per episode, as tracking_lin_vel.

obs["observation"] [N, 42]: columns 0:3 are the base linear velocity x 2 (base frame), columns 6:9 gravity in
the pelvis frame ((0, 0, -1) upright), columns 9:11 the planar command (v_x, v_y) x 2.
"""

DT = 0.02  # s, the control step that scales every Cassie term
SCALE = 1.0


def compute_aux_reward(obs):
    velocity = obs["observation"][:, 0:2] * 0.5  # m/s, undoing the observation scale 2
    gravity = obs["observation"][:, 6:9]
    command = obs["observation"][:, 9:11] * 0.5  # m/s
    command_speed2 = (command * command).sum(-1)  # |c|^2
    # (v . c) / |c|^2: the fraction of the commanded speed achieved along its direction (|c| >= 0.2 when moving)
    progress = (velocity * command).sum(-1) / command_speed2.clamp(min=0.04)
    moving = (command_speed2 > 0.01).float()  # planar commands under 0.2 m/s are zeroed by the task
    # squared sine of the tilt: g_x^2 + g_y^2 (0 upright, 1 lying on the side)
    tilt = (gravity[:, 0] * gravity[:, 0] + gravity[:, 1] * gravity[:, 1]).clamp(0.0, 1.0)
    return SCALE * DT * progress.clamp(0.0, 1.0) * moving * (1.0 - tilt)
