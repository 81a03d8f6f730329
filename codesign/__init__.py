"""The co-design of BALLU in a run (paper Sec. IV): policies.py trains and scores a run's policies and makes
GES's train and score callables from ppo.py, ballu.py and ges.py. run_all.py's stages call it; it imports no
run_all."""
