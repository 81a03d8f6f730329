#!/bin/bash
# A finished overnight rerun (exit 0) becomes docs/overnight/seedN: what a reader opens, not the resume state.
#   SEED=0|1 docs/overnight/rerun_publish.sh      # then write seedN/RUN.md from rerun-sN/RUN.md and commit
# Copied: the report, results, test scores, calibration, stage times, figures; the scored policies (each
# policy_best.pt and every GES run's final best windows, optimiser state dropped: load with ppo.load_policy) with
# their training logs and each GES run's history.json. Moved (one home each): rerun-sN's run_all.log, with the
# last attempt's log (~/runs/rerun/sN.log, which rerun_save.sh appends after an unfinished attempt) appended.
set -e
: "${SEED:?}"
OUT=~/runs/overnight-s$SEED; DOC=/work/main/docs/overnight/seed$SEED; KEEP=/work/main/docs/overnight/rerun-s$SEED
grep -q '"figures"' $OUT/stage_seconds.json || { echo "$OUT has not finished (no figures stage)"; exit 2; }
git -C /work/main rm -rq --ignore-unmatch docs/overnight/seed$SEED && rm -rf $DOC && mkdir -p $DOC
cp $OUT/{REPORT.md,results.json,test_scores.csv,calibration.json,stage_seconds.json} $DOC/
cp -r $OUT/figures $DOC/figures
git -C /work/main mv docs/overnight/rerun-s$SEED/run_all.log $DOC/run_all.log
LOG=~/runs/rerun/s$SEED.log; [ -f $LOG ] && cat $LOG >> $DOC/run_all.log && mv $LOG $LOG.saved   # the last attempt's
cd /work/main && python - $OUT $DOC <<'PY'
import glob, json, os, shutil, sys, torch
out, doc = sys.argv[1:]

def strip(src, dst):
    """A checkpoint without its optimiser state (~1/3 the size), what ppo.load_policy reads."""
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    ck = torch.load(src, map_location="cpu", weights_only=False)
    ck.pop("optimizer", None)
    torch.save(ck, dst)

for d in sorted(glob.glob(os.path.join(out, "policies", "*", ""))):
    name = os.path.basename(d.rstrip("/"))
    if not os.path.exists(os.path.join(d, "policy_best.pt")):
        continue                                  # policies/bo: the cost stage's BO trials, not a scored policy
    strip(os.path.join(d, "policy_best.pt"), os.path.join(doc, "policies", name, "policy_best.pt"))
    shutil.copy(os.path.join(d, "log.csv"), os.path.join(doc, "policies", name, "log.csv"))
for run in sorted(glob.glob(os.path.join(out, "ges", "*", "state.json"))):
    run = os.path.dirname(run)
    dst = os.path.join(doc, "ges", os.path.basename(run))
    for c in json.load(open(os.path.join(run, "state.json")))["ckpt"]:
        best = c.replace(".ckpt", "_best.ckpt")
        strip(os.path.join(run, best), os.path.join(dst, best.split("/")[-1]))
        shutil.copy(os.path.join(run, c + ".csv"), os.path.join(dst, c.split("/")[-1] + ".csv"))
    shutil.copy(os.path.join(run, "history.json"), os.path.join(dst, "history.json"))
print(f"{doc}: {sum(len(f) for _, _, f in os.walk(doc))} files")
PY
du -sh $DOC
