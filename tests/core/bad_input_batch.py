"""Runs many CLI invocations in one fresh process (torch is imported once, not once per case).

    python -m tests.core.bad_input_batch CASES.json RESULTS.json

Each case ``{"module", "args", "env", "cwd"}`` calls ``tridehaze_plugin.cli.<module>.entrypoint()``
with that argv and environment; its exit code and everything written to stderr (file descriptor 2,
so native libraries' own log lines are caught too) are recorded. An exception that escapes the
entry point is recorded as a traceback, exactly what a user would see.
"""

from __future__ import annotations

import importlib
import io
import json
import os
import sys
import tempfile
import traceback


def run_case(case: dict) -> dict:
    module = importlib.import_module(f"tridehaze_plugin.cli.{case['module']}")
    saved_env, saved_cwd, saved_argv = dict(os.environ), os.getcwd(), sys.argv
    os.environ.update(case.get("env", {}))
    os.chdir(case["cwd"])
    sys.argv = [case["module"], *case["args"]]
    code = 0
    with tempfile.TemporaryFile(mode="w+b") as capture:
        sys.stderr.flush()
        saved_fd = os.dup(2)
        os.dup2(capture.fileno(), 2)
        sys.stderr = io.TextIOWrapper(os.fdopen(os.dup(2), "wb"), write_through=True)
        try:
            module.entrypoint()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException:  # noqa: BLE001 - a traceback is exactly what the test must see
            traceback.print_exc()
            code = 1
        finally:
            sys.stderr.flush()
            sys.stderr.close()
            sys.stderr = sys.__stderr__
            os.dup2(saved_fd, 2)
            os.close(saved_fd)
            os.environ.clear()
            os.environ.update(saved_env)
            os.chdir(saved_cwd)
            sys.argv = saved_argv
        capture.seek(0)
        err = capture.read().decode("utf-8", errors="replace")
    return {"returncode": code, "stderr": err}


def main() -> None:
    cases = json.loads(open(sys.argv[1]).read())
    results = {name: run_case(case) for name, case in cases.items()}
    with open(sys.argv[2], "w") as f:
        json.dump(results, f)


if __name__ == "__main__":
    main()
