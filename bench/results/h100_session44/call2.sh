set -u
# session 44, call 2: Y (--fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --near-prune 0.25) on the held-out NeX trex and
# the two seeds call 1's guard skipped (fern 2, room 2), X (Y + --view-warp-scale 2) on trex; full schedule, 3 views,
# three runs at once. Default digits (session 41, docs/results.md §52): trex 22.2115 / 22.5357 / 22.5711 (22.439),
# fern seed 2 22.2134, room seed 2 22.2490.
# Predicted: Y within 0.15 dB of the default's trex mean; X (−0.20 on fern and flower in call 1) lower than Y on trex.
PAR=3; source bench/gpu_call_env.sh .g44 400
X="--fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --view-warp-scale 2 --near-prune 0.25"
Y="--fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --near-prune 0.25"
for s in 0 1 2; do one Y llff_nex trex 3 $s paper $Y; done
one Y llff fern 3 2 paper $Y; one Y llff_nex room 3 2 paper $Y
for s in 0 1 2; do one X llff_nex trex 3 $s paper $X; done
finish
