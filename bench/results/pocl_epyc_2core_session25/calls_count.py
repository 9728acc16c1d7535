"""Python function calls per iteration of the stubbed fine step (bench/results/pocl_epyc_2core_session24/
stubbed_fine_step.py under cProfile, 101 iterations): a deterministic count, where the stubbed step's ms are noisy on
2 cores. docs/results.md §35. Usage: python calls_count.py SRC_TREE (run from the repository root)."""
import cProfile  # noqa: F401
import pstats  # noqa: F401
import sys

src = sys.argv[1]
code = open("bench/results/pocl_epyc_2core_session24/stubbed_fine_step.py").read()
code = code.replace("src, its = sys.argv[1], int(sys.argv[2])", f"src, its = {src!r}, 101")
code = code.replace('with launches_stubbed():\n    h = run(its).history',
                    'pr = cProfile.Profile()\nwith launches_stubbed():\n    pr.enable(); h = run(its).history; pr.disable()\n'
                    'st = pstats.Stats(pr); print("calls per step", st.total_calls / its)')
exec(compile(code, "stubbed_fine_step.py", "exec"))
