#!/bin/bash
# After an attempt stopped (or its process group was killed): the folder's work since experiments.rerun made it,
# as one tarball on main for the next session (rerun_go.sh restores it), and the attempt's log appended.
#   SEED=0|1 docs/overnight/rerun_save.sh
set -e
: "${SEED:?}"
OUT=~/runs/overnight-s$SEED; KEEP=/work/main/docs/overnight/rerun-s$SEED; LOG=~/runs/rerun/s$SEED.log
cd $OUT && { ls ./calibration.json ./manifest.json; find . -type f -newer .prepared ! -name '*.damaged'; } | sort -u > /tmp/delta$SEED.txt
# calibration.json and manifest.json come from experiments.rerun itself: keep the first attempt's, which --plan used
# A finished GES run's earlier rounds' checkpoints are read by no later stage (repair, scoring and the figures read
# state.json's final checkpoints and every round's .csv log): they stay in the folder but not in the tarball.
python - /tmp/delta$SEED.txt <<'PY'
import json, os, sys
files = open(sys.argv[1]).read().split()
drop = set()
for f in files:
    if f.endswith("/state.json") and "/ges/" in "/" + f:
        s = json.load(open(f))
        if s["done"] and (s.get("final") or not s["config"].get("final_train")):
            run = os.path.dirname(f)
            keep = {os.path.join(run, c) for c in s["ckpt"] if c}
            keep |= {k.replace(".ckpt", "_best.ckpt") for k in keep}
            drop |= {g for g in files if g.startswith(run + "/ckpt/") and g.endswith(".ckpt") and g not in keep}
open(sys.argv[1], "w").write("".join(f + "\n" for f in files if f not in drop))
print(f"{len(drop)} earlier-round checkpoints of finished GES runs left out")
PY
tar -czf $KEEP/state.tgz -T /tmp/delta$SEED.txt
[ -f $LOG ] && cat $LOG >> $KEEP/run_all.log && mv $LOG $LOG.saved
echo "$(wc -l < /tmp/delta$SEED.txt) files, $(du -h $KEEP/state.tgz | cut -f1)"
