# fmt: off
# ruff: noqa: W191
# Indented with tabs, as some users write it; the markers give an int before float().


def reward_function(params):
	width = params['track_width']
	gap = params['distance_from_center']

	if gap <= 0.1 * width:
		reward = 1
	elif gap <= 0.25 * width:
		reward = 0.5
	elif gap <= 0.5 * width:
		reward = 0.1
	else:
		return 1e-5

	'''Old version, kept in a string rather than comments (it uses math, which is not imported):
	direction = math.degrees(math.atan2(dy, dx))
	if abs(direction - params['heading']) > 10:
		reward *= 0.5'''

	if params['speed'] < 1.0:
		reward *= 0.75
	return float(reward)
