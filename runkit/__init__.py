"""The machinery of a long run that knows nothing of BALLU, PPO or GES: progress lines and their ETA.

Imports nothing of the project, so every module may import it (ppo.TrainLog, run_all); run_all uploads it to a
Dask cluster as a zip beside the top-level modules."""
