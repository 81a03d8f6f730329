#!/bin/bash
# After an attempt stopped (or its process group was killed): the folder's work since experiments.rerun made it,
# as one tarball on main for the next session (rerun_go.sh restores it), and the attempt's log appended.
#   SEED=0|1 docs/overnight/rerun_save.sh
set -e
: "${SEED:?}"
OUT=~/runs/overnight-s$SEED; KEEP=/work/main/docs/overnight/rerun-s$SEED; LOG=~/runs/rerun/s$SEED.log
cd $OUT && { ls ./calibration.json ./manifest.json; find . -type f -newer .prepared ! -name '*.damaged'; } | sort -u > /tmp/delta$SEED.txt
# calibration.json and manifest.json come from experiments.rerun itself: keep the first attempt's, which --plan used
tar -czf $KEEP/state.tgz -T /tmp/delta$SEED.txt
[ -f $LOG ] && cat $LOG >> $KEEP/run_all.log && mv $LOG $LOG.saved
echo "$(wc -l < /tmp/delta$SEED.txt) files, $(du -h $KEEP/state.tgz | cut -f1)"
