#!/bin/bash
# One timed attempt of an overnight rerun, alone on the machine; rerun the same command to go on.
#   COMMIT=<sha> SEED=0|1 STOP=HH:MM docs/overnight/rerun_go.sh   # from /work/main
# A new machine (each session may be one) rebuilds the folder: experiments.rerun's baselines from git history,
# then the delta committed on main at docs/overnight/rerun-sN/state.tgz (rerun_save.sh) on top.
set -e
: "${COMMIT:?}" "${SEED:?}" "${STOP:?}"
WT=~/wt_rerun; OUT=~/runs/overnight-s$SEED; KEEP=/work/main/docs/overnight/rerun-s$SEED
[ -d $WT ] || git -C /work/main worktree add --detach $WT $COMMIT
[ "$(git -C $WT rev-parse HEAD)" = "$(git -C /work/main rev-parse $COMMIT)" ] || { echo "$WT is not at $COMMIT"; exit 2; }
cd $WT
case $SEED in 0) STATE=9eb76ac:docs/overnight/seed0/state;; 1) STATE=d06d56e:docs/overnight/seed1/state.tar;; esac
mkdir -p $KEEP
if [ ! -d $OUT ]; then
  python -m experiments.rerun docs/overnight/seed$SEED --state $STATE --out $OUT
  touch $OUT/.prepared
  if [ -f $KEEP/state.tgz ]; then
    tar -xmzf $KEEP/state.tgz -C $OUT       # -m: restored files count as newer than .prepared for the next save
    echo "restored $KEEP/state.tgz"
  else
    python run_all.py --preset overnight --seed $SEED --out $OUT --workers 2 --plan | tee $KEEP/plan.txt
  fi
fi
START=$(date -u +%FT%T)
set +e
python run_all.py --preset overnight --seed $SEED --out $OUT --workers 2 --stop-by $STOP
RC=$?
echo "$START $(date -u +%FT%T) rc=$RC commit=$COMMIT cpu=$(lscpu | sed -n 's/Model name: *//p')" >> $KEEP/attempts.txt
exit $RC
