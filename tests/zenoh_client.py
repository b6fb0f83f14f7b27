#!/usr/bin/env python3
"""An independent Zenoh client (eclipse-zenoh, not RIS code) driving a running risd:
scan request -> scan_id, state publications ending in done, a binary-PLY cloud per sensor and
merged, an error reply for a malformed request, a second scan followed by a slow subscriber
(each cloud's callback sleeps, so risd's link to it stays congested while `done` goes out),
stored results queryable.

Usage: zenoh_client.py ENDPOINT CELL SENSOR... ; exit status 0 when every check passed."""

import faulthandler
import json
import os
import sys
import threading
import time

import zenoh


def main():
    endpoint, cell, sensors = sys.argv[1], sys.argv[2], sys.argv[3:]
    # A stalled step prints every thread's stack and ends the client instead of hanging.
    faulthandler.dump_traceback_later(240, exit=True)
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    lock = threading.Lock()
    states, clouds, reports = {}, {}, {}
    slow = set()  # scans whose clouds this client takes slowly

    def on_sample(sample):
        key = str(sample.key_expr)
        parts = key.split("/")
        delay = False
        with lock:
            if parts[-1] == "state":
                states.setdefault(parts[3], []).append(json.loads(sample.payload.to_bytes()))
            elif parts[-2] == "cloud":
                clouds.setdefault(parts[3], {})[parts[-1]] = sample.payload.to_bytes()
                delay = parts[3] in slow
            elif parts[-1] == "report":
                reports[parts[3]] = json.loads(sample.payload.to_bytes())
        if delay:
            # A slow consumer: nothing more is read from this link while the callback runs.
            time.sleep(1.0)

    # Called on Zenoh's network thread (not a Python thread of its own), so a slow callback
    # is a slow consumer as risd sees it.
    handler = zenoh.handlers.Callback(on_sample, indirect=False)
    sub = session.declare_subscriber(f"ris/{cell}/scans/**", handler)

    def ask(payload):
        replies = list(session.get(f"ris/{cell}/scan", payload=payload, timeout=10.0))
        assert len(replies) == 1, f"{len(replies)} replies"
        r = replies[0]
        if r.ok is not None:
            return json.loads(r.ok.payload.to_bytes()), None
        return None, r.err.payload.to_bytes().decode()

    def wait_done(scan_id, timeout=120):
        end = time.time() + timeout
        while time.time() < end:
            with lock:
                seq = states.get(scan_id, [])
                if seq and seq[-1]["state"] in ("done", "failed"):
                    return seq
            time.sleep(0.2)
        with lock:
            got = sorted(clouds.get(scan_id, {}))
            last = states.get(scan_id, [])[-3:]
        raise AssertionError(f"scan {scan_id} did not finish in {timeout} s: last states {last}, "
                             f"clouds received {got}")

    ok, err = ask("{not json")
    assert ok is None and "malformed" in err, (ok, err)
    print("malformed request refused:", err)
    ok, err = ask(json.dumps({"sensors": ["nope"]}))
    assert ok is None and "nope" in err, (ok, err)
    ok, err = ask(json.dumps({"part": "nope"}))
    assert ok is None and "nope" in err, (ok, err)

    # The cell defines one part: the first scan inspects it by default, the second is told not to.
    for n, inspect in enumerate([None, False]):
        request = {"tag": f"client test {n}"}
        if inspect is not None:
            request["inspect"] = inspect
        ok, err = ask(json.dumps(request))
        assert err is None, err
        assert ok["state"] == "accepted", ok
        scan_id = ok["scan_id"]
        if inspect is False:
            with lock:
                slow.add(scan_id)
        seq = wait_done(scan_id)
        names = [s["state"] for s in seq]
        assert names[-1] == "done", seq[-1]
        assert "acquiring" in names and "reconstructing" in names and "merging" in names, names
        time.sleep(0.5)
        with lock:
            got = clouds.get(scan_id, {})
            report = reports.get(scan_id)
        if inspect is None:
            assert "inspecting" in names, names
            # The simulated panel is the CAD surface: the part passes with the sensors' noise.
            assert report is not None, "no report published"
            st = report["statistics"]
            assert report["verdict"] == "pass", report["reasons"]
            assert abs(st["mean"]) < 0.05 and st["rms"] < 0.15, st
            assert st["within_tolerance"] > 0.999 and st["points"] > 1_000_000, st
            assert seq[-1]["inspection"]["verdict"] == "pass", seq[-1]
            print(f"inspection: {report['verdict']}, RMS {st['rms']:.3f} mm, "
                  f"{st['points']} points, {st['beyond_cad']} beyond the CAD")
            inspected = scan_id
        else:
            assert "inspecting" not in names and report is None, names
        for s in sensors + ["merged"]:
            assert s in got, f"no cloud {s} for {scan_id}: {sorted(got)}"
            head = got[s][:200]
            assert head.startswith(b"ply\nformat binary_little_endian"), head[:40]
        print(f"scan {scan_id}: {len(seq)} states, clouds {sorted(got)}, "
              f"{seq[-1].get('merged_points')} merged points, "
              f"{seq[-1].get('compute_after_last_frame'):.2f} s compute after the last frame")

    stored = list(session.get(f"ris/{cell}/scans/{scan_id}/cloud/merged", timeout=10.0))
    assert len(stored) == 1 and stored[0].ok is not None, stored
    assert stored[0].ok.payload.to_bytes().startswith(b"ply\n")
    # The inspected scan's page and labelled map are served too.
    page = list(session.get(f"ris/{cell}/scans/{inspected}/page", timeout=10.0))
    assert len(page) == 1 and page[0].ok is not None, page
    html = page[0].ok.payload.to_bytes()
    assert html.startswith(b"<!DOCTYPE html>") and b">PASS<" in html, html[:200]
    png = list(session.get(f"ris/{cell}/scans/{inspected}/map", timeout=10.0))
    assert len(png) == 1 and png[0].ok.payload.to_bytes().startswith(b"\x89PNG"), png
    print(f"stored page {len(html)} bytes and map of {inspected}", flush=True)
    health = list(session.get(f"ris/{cell}/health", timeout=5.0))
    assert health and health[0].ok is not None
    print("health:", health[0].ok.payload.to_bytes().decode(), flush=True)
    sub.undeclare()
    session.close()
    print("1 passed, 0 failed", flush=True)
    faulthandler.cancel_dump_traceback_later()


if __name__ == "__main__":
    # A failed check must end the process: with a Zenoh session still open, the interpreter's
    # own shutdown can wait forever on the session's threads, so the exit is immediate.
    try:
        main()
        code = 0
    except BaseException:  # noqa: BLE001 - every failure is reported the same way
        import traceback

        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
