#!/usr/bin/env python3
"""Peak memory of `plausible` on inputs just under 200 MB.

The hardening rule: for any input under 200 MB the resident set stays below
2 GB (no unbounded memory). This script writes such inputs into a temporary
folder (a pose list, a dense mesh, a results CSV, a scene, oversized
images), runs each command under /usr/bin/time and prints its peak RSS and
exit status; it exits 1 if any peak is at or above the limit, or a command
panics (exit 101) or aborts (134).

    python3 scripts/rss_audit.py [--bin target/release/plausible] [--mb 190]
"""
import argparse, json, math, os, random, struct, subprocess, sys, tempfile, zlib

LIMIT_MB = 2048


def png(path, w, h, bits=16):
    """A w×h grey PNG of zeros, written without decoding cost (rows of 0)."""
    raw = zlib.compress(b"".join(b"\0" + b"\0" * (w * bits // 8) for _ in range(h)), 1)
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, bits, 0, 0, 0, 0)) + chunk(b"IDAT", raw) + chunk(b"IEND", b""))


def poses_json(path, mb):
    """Poses 2 m to the side of the camera's view (culled before dispatch)."""
    row = '{"cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [2000.0, 0.0, 600.0]}'
    n = mb * 1_000_000 // (len(row) + 2)
    with open(path, "w") as f:
        f.write("[" + ",\n".join([row] * n) + "]\n")
    return n


def sphere_obj(path, mb):
    """A UV sphere of radius 5 cm with about mb MB of OBJ text."""
    per = 60  # bytes per vertex line + 2 faces
    n = int(math.sqrt(mb * 1_000_000 / per))
    with open(path, "w") as f:
        for i in range(1, n):
            th = math.pi * i / n
            for j in range(n):
                ph = 2 * math.pi * j / n
                f.write(f"v {0.05*math.sin(th)*math.cos(ph):.6f} {0.05*math.sin(th)*math.sin(ph):.6f} {0.05*math.cos(th):.6f}\n")
        f.write("v 0 0 0.05\nv 0 0 -0.05\n")
        top, bot = (n - 1) * n + 1, (n - 1) * n + 2
        idx = lambda i, j: (i - 1) * n + (j % n) + 1
        for j in range(n):
            f.write(f"f {top} {idx(1, j)} {idx(1, j + 1)}\n")
            f.write(f"f {bot} {idx(n - 1, j + 1)} {idx(n - 1, j)}\n")
        for i in range(1, n - 1):
            for j in range(n):
                a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
                f.write(f"f {a} {c} {b}\nf {b} {c} {d}\n")
    return 2 * n * (n - 1)


def results_csv(path, mb, dataset):
    """Random estimates for the dataset's targeted images (scene_id, im_id, obj_id)."""
    targets = json.load(open(os.path.join(dataset, "test_targets_bop19.json")))
    rng = random.Random(0)
    with open(path, "w") as f:
        f.write("scene_id,im_id,obj_id,score,R,t,time\n")
        size = 0
        while size < mb * 1_000_000:
            t = rng.choice(targets)
            line = f"{t['scene_id']},{t['im_id']},{t['obj_id']},{rng.random():.6f},1 0 0 0 1 0 0 0 1,{rng.uniform(-100,100):.3f} {rng.uniform(-100,100):.3f} {rng.uniform(700,1000):.3f},-1\n"
            f.write(line)
            size += len(line)


ONLY = ""


def run(name, args, env=None):
    if ONLY not in name:
        return True
    out = subprocess.run(["/usr/bin/time", "-f", "%M"] + args, capture_output=True, text=True, env=env)
    lines = out.stderr.strip().splitlines()
    rss_mb = int(lines[-1]) / 1024 if lines and lines[-1].isdigit() else float("nan")
    tail = next((l for l in reversed(lines[:-1]) if l.strip() and not l.startswith("Command exited")), "")[:110]
    bad = rss_mb >= LIMIT_MB or out.returncode in (101, 134) or math.isnan(rss_mb)
    print(f"{'FAIL' if bad else 'ok  '} {name:<38} exit {out.returncode:>3}  peak {rss_mb:8.1f} MB  {tail}", flush=True)
    return not bad


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default="target/release/plausible")
    ap.add_argument("--mb", type=int, default=190)
    ap.add_argument("--only", default="", help="run only the cases whose name contains this")
    a = ap.parse_args()
    global ONLY
    ONLY = a.only
    exe = os.path.abspath(a.bin)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ok = True
    with tempfile.TemporaryDirectory() as d:
        demo = os.path.join(d, "demo")
        subprocess.run([exe, "demo", "--n", "16", "--device", "cpu", "--out", demo], check=True, capture_output=True)
        obs = ["--camera", f"{demo}/camera.json", "--depth", f"{demo}/depth.png", "--mask", f"{demo}/mask.png"]
        mesh = ["--mesh", f"{demo}/duck_0.15m.obj"]
        n = poses_json(f"{d}/poses.json", a.mb)
        ok &= run(f"score: {n} poses ({a.mb} MB JSON)", [exe, "score", *mesh, *obs, "--poses", f"{d}/poses.json", "--device", "cpu", "--quiet", "--top", "1"])
        os.remove(f"{d}/poses.json")
        tris = sphere_obj(f"{d}/sphere.obj", a.mb)
        with open(f"{d}/one.json", "w") as f:
            f.write('[{"cam_R_m2c": [1,0,0,0,1,0,0,0,1], "cam_t_m2c": [0, 0, 600]}]')
        ok &= run(f"score: mesh of {tris} triangles", [exe, "score", "--mesh", f"{d}/sphere.obj", "--mesh-units", "m", *obs[:4], "--poses", f"{d}/one.json", "--device", "cpu", "--quiet"])
        ok &= run("score --physics: same mesh", [exe, "score", "--mesh", f"{d}/sphere.obj", "--mesh-units", "m", *obs[:4], "--poses", f"{d}/one.json", "--plane", f"{demo}/plane.json", "--physics", "--device", "cpu", "--quiet"])
        ok &= run("stable-poses: same mesh, 4 drops", [exe, "stable-poses", f"{d}/sphere.obj", "--mesh-units", "m", "--drops", "4", "--quiet", "--db", f"{d}/s.sqlite"])
        os.remove(f"{d}/sphere.obj")
        png(f"{d}/big.png", 8000, 8000)
        ok &= run("score: 8000x8000 depth PNG", [exe, "score", *mesh, "--camera", f"{demo}/camera.json", "--depth", f"{d}/big.png", "--poses", f"{d}/one.json", "--device", "cpu", "--quiet"])
        png(f"{d}/bigmask.png", 20000, 20000, bits=8)
        ok &= run("score: 20000x20000 mask PNG", [exe, "score", *mesh, *obs[:4], "--mask", f"{d}/bigmask.png", "--poses", f"{d}/one.json", "--device", "cpu", "--quiet"])
        ok &= run("plane: 8000x8000 depth PNG", [exe, "plane", "--camera", f"{demo}/camera.json", "--depth", f"{d}/big.png", "--out", f"{d}/p.json"])
        dataset = os.path.join(root, "assets", "lmo-synth")
        results_csv(f"{d}/results.csv", a.mb, dataset)
        ok &= run(f"eval: {a.mb} MB results CSV", [exe, "eval", "--dataset", dataset, "--results", f"{d}/results.csv", "--errors", "mssd,mspd", "--device", "cpu"])
        os.remove(f"{d}/results.csv")
        with open(f"{d}/scene.json", "w") as f:
            obj = {"name": "duck", "mesh": f"{demo}/duck_0.15m.obj", "units": "m", "R": [1, 0, 0, 0, 1, 0, 0, 0, 1], "t": [0, 0, 0.2]}
            f.write('{"planes": [{"point": [0, 0, 0], "normal": [0, 0, 1]}], "objects": [' + ",".join([json.dumps(obj)] * (a.mb * 1_000_000 // 150)) + "]}")
        ok &= run(f"check: {a.mb} MB scene JSON", [exe, "check", f"{d}/scene.json"])
    print("all peaks below 2 GB, no panic or abort" if ok else "FAILED")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
