"""Study tooling that sits on top of the library modules (ballu, ppo, ges, tpe, run_all): each file is one study,
runnable as `python -m experiments.NAME`; its results and reading live in docs/NAME-of-the-study/."""
