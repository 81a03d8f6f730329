"""The machinery of a long run that knows nothing of BALLU, PPO or GES: progress.py (progress lines and the one
ETA formula), files.py (atomic JSON, damaged files), logs.py (the training log), folder.py (the output folder,
the code hash), box.py (the design box: names, bounds, the unit cube), clock.py (a stage's wall time), pool.py (Dask, the process pool, jobs side by side), stats.py (the
report's statistics), plan.py (what a preset costs: --plan's arithmetic from a preset's numbers, --rates'
measurement), lanes.py (a batched env's lanes in worker processes, given the env's constructor; scoring lanes in
them), cli.py (the command line of a run made of stages, given the experiment: run_all.EXPERIMENT).

Imports nothing of the project outside itself, so every module may import it (ppo.TrainLog, run_all, report/);
run_all uploads it to a Dask cluster as a zip before the top-level modules."""
