"""Run a script after executing the Python in $PRE (';'-separated statements): python3 pre.py script.py args..."""
import os, runpy, sys
code = os.environ.get("PRE", "")
if code:
    exec(code.replace(";", "\n"))
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
