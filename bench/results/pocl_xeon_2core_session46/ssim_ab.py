"""The four CPU SSIM passes with SSIM_VTAIL=0 against 1 at SSIM_VW 16 (builds alternating; every output
byte-compared): bench/results/pocl_epyc_2core_session47/ssim_ab2.py with those two builds, 30 repetitions.
argv: [H W] (default 378 x 504). Its output lines are ssim_ab2.py's; ab_console.txt's came from this script's earlier
form (the same measurement, printed as "ms VTAIL=0 [...] VTAIL=1 [...] ratios [...] sum ratio")."""
import runpy
import sys
from pathlib import Path

sys.argv = ["ssim_ab2.py", "SSIM_VW=16,SSIM_VTAIL=0", "SSIM_VW=16,SSIM_VTAIL=1", "30", *sys.argv[1:3]]
runpy.run_path(str(Path(__file__).resolve().parents[1] / "pocl_epyc_2core_session47" / "ssim_ab2.py"), run_name="__main__")
