"""lmjx: keep a robot arm with locked joints useful, with whole-body non-prehensile actions.

Public API (everything else is internal):
  load_robot()            the Panda model and its static kernel description
  parse_failure(spec)     'none', 'case1', 'case2' or 'J2=0.3,J4=-1.5'
  reach_map(failure, cfg) the Reach-Ability map (paper Algorithm 1)
"""

__version__ = "0.1.0"
