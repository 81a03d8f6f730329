"""PPO protocol fork screen (previous robot): lr_cap obstacle seed 0 resumed from its committed 1 M checkpoint with
the action std held <= 0.4 (its value at 1 M; PPOConfig.max_std), to 2 M and 3 M; lr_cap itself grew the std to
0.50 / 0.63 there.
Made by: copying docs/ppo_protocol/archive/previous_robot/lr_cap/obstacle/seed0's policy_1000000.pt, long_runs/lr_cap/
obstacle/seed0's result_1000000.json and the log rows up to the checkpoint's steps into FOLDER (the tooling resumes
from the last policy_<steps>.pt), then, from the repo root:
    PYTHONPATH=. python docs/ppo_protocol/archive/previous_robot/long_runs/fork_std04_from_lr_cap_1M/fork.py FOLDER
The committed run is obstacle/seed0 beside this file; its 1 M checkpoint and result are not kept there (they are
byte-identical to the files named above). It was made on the previous robot: give a fresh FOLDER, not the archive."""
import sys
import ppo
from experiments import ppo_protocol


def main(folder):
    res = ppo_protocol.run_one(folder, {**ppo_protocol.LR_CAP, "max_std": 0.4}, "obstacle", 0,
                               [1_000_000, 2_000_000, 3_000_000], ppo_protocol.protocol_designs(12), 20, 2,
                               ppo.PPOConfig())
    for r in res:
        print(r["steps"], round(r["mean_J"], 1), round(r["train_level"], 1), flush=True)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
