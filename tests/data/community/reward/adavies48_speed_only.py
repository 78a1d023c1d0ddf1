def reward_function(params):
    '''
    Example of rewarding the agent to follow center line
    '''
    
    # Read input parameters
    speed = params['speed']
  
    
    return float(speed)
