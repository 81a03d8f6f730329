"""Issue 16 fork screen: lr_cap obstacle seed 0 resumed from its committed 1 M checkpoint with the action std held
<= 0.4 (its value at 1 M; PPOConfig.max_std), to 2 M and 3 M; lr_cap itself grew the std to 0.50 / 0.63 there.
Made by: copying docs/ppo_protocol/lr_cap/obstacle/seed0's policy_1000000.pt (also as policy.pt),
result_1000000.json and the log rows up to the checkpoint's steps into FOLDER, then, from the repo root:
    PYTHONPATH=. python docs/ppo_long/fork_std04_from_lr_cap_1M/fork.py FOLDER
(on the committed folder it resumes: every milestone is already scored)."""
import sys
import ppo


def main(folder):
    res = ppo._protocol_run(folder, {**ppo.LR_CAP, "max_std": 0.4}, "obstacle", 0, [1_000_000, 2_000_000, 3_000_000],
                            ppo.protocol_designs(12), 20, 2, ppo.PPOConfig())
    for r in res:
        print(r["steps"], round(r["mean_J"], 1), round(r["train_level"], 1), flush=True)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/ppo_long/fork_std04_from_lr_cap_1M/obstacle/seed0")
