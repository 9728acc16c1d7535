set -u
# session 12, call 2: LLFF 3 views with --prune-unseen (the Gaussians no training pixel blends, dropped at each
# densification) on call 1's collapsed cells, and a rerun of the collapsed flower_drop seed 2 whose model comes back.
# The working tree had a helper's unfinished kernel change: the call restores those files to HEAD first
# (.gpu_s12a/orig holds them), so the runs use the kernels of HEAD plus the prune_unseen change.
cp -r .gpu_s12a/orig/. . && bash .gpu_s12a/orig_rm.sh
bash bench/results/h100_session11/call_runs.sh .gpu_s12a 540 bench/results/h100_session12/runs2.txt
d=$(dirname $(find /tmp/g/flower_drop_diag -name gaussians.ply | head -1))
tar cf $OUT/diag_model.tar -C $d gaussians.ply cameras.json metrics.json config.toml
