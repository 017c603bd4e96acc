#!/usr/bin/env python3
"""Puts a daemon into a known state before Schemathesis, and leaves no run going after it.

usage: rig.py seed URL      as operator `ada`: start tests/api/long-run.toml (6561 cheap
                            captures) into dataset st-seed (run r1), wait for a few captures
                            and leave it running: the run holds the rig while Schemathesis runs
       rig.py cleanup URL   as admin: abort every run that is not over, wait until each is
                            over; prints how many runs there were
Standard library only (the daemon's own Python is not needed).
"""
import json
import os
import sys
import time
import urllib.error
import urllib.request

OVER = ("finished", "aborted", "interrupted", "failed")


def call(base, token, method, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + "/api/v1" + path, data=data, method=method,
                                 headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=20) as r:
            return r.status, json.load(r)
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


def wait(base, run_id, pred, what, timeout=120):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        _, s = call(base, "admin-token", "GET", f"/runs/{run_id}")
        if pred(s):
            return s
        time.sleep(0.2)
    sys.exit(f"run {run_id}: {what} not reached in {timeout} s: {s}")


def seed(base):
    with open(os.path.join(os.path.dirname(os.path.abspath(__file__)), "long-run.toml")) as f:
        plan = f.read()
    code, s = call(base, "operator-token", "POST", "/runs", {"plan_text": plan, "dataset": "st-seed"})
    if code != 201:
        sys.exit(f"starting the seed run: {code} {s}")
    rid = s["id"]
    s = wait(base, rid, lambda s: s["done"] >= 3 or s["state"] in OVER, "3 captures")
    if s["state"] != "running":
        sys.exit(f"the seed run is not going before Schemathesis starts: {s}")
    print(f"# seed: run {rid} {s['state']} at {s['done']}/{s['total']} captures, dataset {s['dataset']}")


def cleanup(base):
    code, r = call(base, "admin-token", "GET", "/runs")
    if code != 200:
        sys.exit(f"listing runs: {code} {r}")
    runs = r["runs"]
    left = [s for s in runs if s["state"] not in OVER]
    for s in left:
        code, p = call(base, "admin-token", "POST", f"/runs/{s['id']}/abort")
        if code not in (200, 409):  # 409: it ended or is stopping meanwhile
            print(f"# aborting {s['id']} ({s['state']}): {code} {p}")
    for s in left:
        wait(base, s["id"], lambda s: s["state"] in OVER, "over", timeout=60)
    print(f"# runs during the test: {len(runs)}; still going at its end and aborted: {len(left)}")


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("seed", "cleanup"):
        sys.exit(__doc__)
    {"seed": seed, "cleanup": cleanup}[sys.argv[1]](sys.argv[2].rstrip("/"))
