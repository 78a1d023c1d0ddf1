# ruff: noqa
# fmt: off
# AWS DeepRacer's documented reward-function example 2, "Stay inside the two borders in time trials", from the
# AWS DeepRacer Developer Guide ("AWS DeepRacer reward function examples";
# source: github.com/awsdocs/aws-deepracer-developer-guide,
# doc_source/deepracer-reward-function-examples.md). AWS publishes the code samples in
# its documentation under the MIT-0 license.
# Shipped unmodified (below this comment, whitespace included) so users can compare
# racer's rewards with DeepRacer's; the lint/format pragmas above keep tools from
# "fixing" it.

def reward_function(params):
    '''
    Example of rewarding the agent to stay inside the two borders of the track
    '''
    
    # Read input parameters
    all_wheels_on_track = params['all_wheels_on_track']
    distance_from_center = params['distance_from_center']
    track_width = params['track_width']
    
    # Give a very low reward by default
    reward = 1e-3

    # Give a high reward if no wheels go off the track and 
    # the car is somewhere in between the track borders 
    if all_wheels_on_track and (0.5*track_width - distance_from_center) >= 0.05:
        reward = 1.0

    # Always return a float value
    return reward
