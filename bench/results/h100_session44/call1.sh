set -u
# session 44, call 1: two option sets, full schedule, seeds 0-2, three runs at once on the GPU (the digits do not
# depend on it; the times do), against session 41's default digits (docs/results.md §52):
#   X = --fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --view-warp-scale 2 --near-prune 0.25  (~893 s on 2 CPU cores
#       at session 40's machine speed [estimate], §54)
#   Y = --fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --near-prune 0.25                      (X without the view_warp
#       term at 1/2)
# Predicted: X and Y within 0.15 dB of the default's means at 3 views (fern 22.257, flower 21.319, room 21.956) and at
# 2 views (fern 21.330, flower 20.031); no collapsed run (every seed above 20.5 dB at 3 views).
PAR=3; source bench/gpu_call_env.sh .gpu30 470
X="--fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --view-warp-scale 2 --near-prune 0.25"
Y="--fit-scale 2,2,1 --fit-scale-share 1,0.5,1 --near-prune 0.25"
for s in 0 1 2; do one X llff flower 3 $s paper $X; one X llff fern 3 $s paper $X; one X llff_nex room 3 $s paper $X; done
for s in 0 1 2; do one X llff flower 2 $s paper $X; one X llff fern 2 $s paper $X; done
for s in 0 1 2; do one Y llff flower 3 $s paper $Y; one Y llff fern 3 $s paper $Y; one Y llff_nex room 3 $s paper $Y; done
finish
