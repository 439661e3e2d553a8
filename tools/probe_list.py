"""The probes of tools/probe_pass.py: (what a careful program does, the command line after
``python -m``). ``OUT`` is the probe's own output path (a fresh name in the scratch folder);
``REAL/`` the shared real photos (those probes are skipped where the folder is absent); names
in capitals are the spoiled copies tools/probe_fixtures.py makes."""

from __future__ import annotations

from probe_fixtures import REPO, SMALL

PROBES = [
    # -- synth scene ---------------------------------------------------------------------------
    ("ok", "synth scene --out OUT.xml"),
    ("ok", "synth scene --layout grid --spacing 100 --half-width 300 --out OUT.xml"),
    ("ok", "synth scene --cameras 3 --out OUT.xml"),
    ("ok", "synth scene --cameras 5 --arrangement ring --out OUT.xml"),
    ("ok", "synth scene --port dome --out OUT.xml"),
    ("ok", "synth scene --port per-camera --port-distance 60,70 --out OUT.xml"),
    ("bad", "synth scene --rig c2air/calib.yaml --out OUT.xml"),
    ("ok", "synth scene --rig ds2/calib.yaml --out OUT.xml"),
    ("ok", "synth scene --rig ds3/calib.yaml --out OUT.xml"),
    ("ok", "synth scene --rig dshouse/calib.yaml --out OUT.xml"),
    ("ok", "synth scene --rig dsdome/calib.yaml --out OUT.xml"),
    ("bad", "synth scene --rig c1air/camera.yaml --out OUT.xml"),
    ("bad", "synth scene --rig c4air --out OUT.xml"),
    ("bad", "synth scene --rig nothere.yaml --out OUT.xml"),
    ("bad", "synth scene --cameras 1 --out OUT.xml"),
    ("bad", "synth scene --cameras 0 --out OUT.xml"),
    ("bad", "synth scene --cameras -2 --out OUT.xml"),
    ("bad", "synth scene --z -5 --out OUT.xml"),
    ("bad", "synth scene --z nan --out OUT.xml"),
    ("bad", "synth scene --z inf --out OUT.xml"),
    ("bad", "synth scene --layout grid --spacing 0 --out OUT.xml"),
    ("bad", "synth scene --layout nosuch --out OUT.xml"),
    ("bad", "synth scene --port nosuch --out OUT.xml"),
    ("bad", "synth scene --port-distance 60,70 --out OUT.xml"),
    ("bad", "synth scene --port per-camera --port-distance 60,70,80 --out OUT.xml"),
    ("bad", "synth scene --size 0 268 --out OUT.xml"),
    ("bad", "synth scene --size 320 --out OUT.xml"),
    ("bad", "synth scene --focal -1 --out OUT.xml"),
    ("bad", "synth scene --out ds2"),
    ("bad", "synth scene --out /proc/x.xml"),
    ("bad", "synth scene --out pair.xml.d/x.xml"),
    ("bad", "synth scene --out ''"),
    ("bad", "synth scene --arrangement ring --out OUT.xml"),
    ("bad", "synth scene --cameras 3 --port dome --port-distance 50 --out OUT.xml"),
    # -- synth render / dataset ----------------------------------------------------------------
    ("ok", f"synth render {REPO}/scenes/paper_plane.xml {SMALL} --spp 4 --out OUT --no-progress"),
    ("ok", "synth dataset pair.xml -D width=320 -D height=268 --spp 4 --out OUT --no-progress"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml {SMALL} --spp 0 --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml -D width=-5 --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml -D nosuch=3 --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml -D width=abc --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml -D seed=4294967296 --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml -D n_water=0.9 --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml {SMALL} --spp 4 --seed 1 -D seed=2 "
            f"--out OUT"),
    ("bad", "synth render nothere.xml --out OUT"),
    ("bad", "synth render ds2/calib.yaml --out OUT"),
    ("bad", "synth render ds2 --out OUT"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml {SMALL} --out ds2"),
    ("bad", f"synth render {REPO}/scenes/paper_plane.xml {SMALL} --out /proc/x"),
    ("bad", f"synth dataset {REPO}/scenes/small_grid.xml {SMALL} --spp 4 --out p2air"),
    ("bad", f"synth dataset {REPO}/scenes/paper_plane.xml -D width=320 --spp 4 --variant nosuch "
            f"--out OUT"),
    ("bad", f"synth dataset {REPO}/scenes/paper_plane.xml {SMALL} --sensor nosuch --out OUT"),
    ("ok", "synth dataset three.xml --spp 16 --out ds3 --no-progress"),  # up to date
    # -- synth boards / sequence / photos / check ----------------------------------------------
    ("bad", "synth boards pair.xml --squares 7x7 --square-mm 60 --out OUT"),
    ("bad", "synth boards pair.xml --squares 7x6 --square-mm 0 --out OUT"),
    ("bad", "synth boards pair.xml --squares 7x6 --square-mm 60 --poses 0 --out OUT"),
    ("bad", "synth boards pair.xml --squares 7x6 --square-mm 60 --distance 900 450 --out OUT"),
    ("bad", "synth boards pair.xml --squares 70x60 --square-mm 60 --out OUT"),
    ("bad", "synth boards pair.xml --squares 7x6 --square-mm 60 --air -D n_water=1.4 --out OUT"),
    ("bad", "synth boards nothere.xml --out OUT"),
    ("bad", "synth boards pair.xml --squares 7x6 --square-mm 60 --board nosuch --out OUT"),
    ("ok", f"synth sequence {REPO}/scenes/small_grid.xml -D width=640 -D height=536 --approach "
           f"1800,1300 --frames 2 --spp 4 --marker-radius-mm 15 --out OUT --no-progress"),
    ("bad", f"synth sequence {REPO}/scenes/small_grid.xml --approach 50,1000 --frames 2 "
            f"--out OUT"),
    ("bad", f"synth sequence {REPO}/scenes/small_grid.xml --approach 1800,1300 --frames 0 "
            f"--out OUT"),
    ("bad", f"synth sequence {REPO}/scenes/small_grid.xml --approach 1800 --frames 2 --out OUT"),
    ("bad", "synth sequence three.xml --approach 2000,1000 --frames 2 --out OUT"),
    ("bad", f"synth sequence {REPO}/scenes/small_grid.xml --trajectory nothere.txt --out OUT"),
    ("ok", "synth photos ds2 --out OUT"),
    ("ok", "synth photos ds3 --out OUT"),
    ("ok", "synth photos b4water --out OUT --format png"),
    ("bad", "synth photos p2air --out OUT"),
    ("bad", "synth photos nothere --out OUT"),
    ("bad", "synth photos ds2 --out OUT --format gif"),
    ("bad", "synth photos ds2 --out OUT --format png --quality 80"),
    ("bad", "synth photos ds2 --out OUT --quality 101"),
    ("bad", "synth photos ds2 --out ds2"),
    ("ok", "synth check ds2"),
    ("ok", "synth check ds3"),
    ("ok", "synth check dsdome"),
    ("bad", "synth check nothere"),
    ("bad", "synth check p2air"),
    ("bad", "synth check c2air"),
    ("bad", "synth suite nothere.toml --out OUT"),
    ("bad", "synth suite pair.xml --out OUT"),
    # -- eval run ------------------------------------------------------------------------------
    ("ok", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --out OUT --no-progress "
           f"--no-figures"),
    ("ok", "eval run three.xml --from ds3 --out OUT --no-progress"),
    ("ok", "eval run domes.xml --from dsdome --out OUT --no-progress "
           "--no-figures"),
    ("ok", "eval run housings.xml --from dshouse --out OUT --no-progress --no-figures"),
    ("bad", "eval run three.xml --from ds2 --out OUT"),
    ("bad", "eval run four.xml --from ds3 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/paper_plane.xml --from ds3 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/paper_plane.xml --from ds2 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --spp 4 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 -D width=640 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/paper_plane.xml --from nothere --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --methods nosuch --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --gate-mm -1 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --gate-mm inf --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --calib c1air/camera.yaml "
            f"--out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --calib c4air/calib.yaml "
            f"--out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --calib c2air --out OUT"),
    ("bad", "eval run three.xml --from ds3 --calib c2air/calib.yaml --out OUT"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --out ds3"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --out /proc/x"),
    ("bad", f"eval run {REPO}/scenes/small_grid.xml --from ds2 --assume n_water=abc --out OUT"),
    ("bad", "eval run nothere.xml --out OUT"),
    ("bad", "eval run ds2 --out OUT"),
    ("bad", f"eval run {REPO}/scenes/speckle_plane.xml --from ds2 --out OUT"),
    # -- eval measure --------------------------------------------------------------------------
    ("ok", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --out OUT "
           "--no-progress"),
    ("ok", "eval measure --calib ds2/calib.yaml ph2/left ph2/right --out OUT --no-progress"),
    ("ok", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam1/image.png "
           "ds3/cam2/image.png --out OUT --no-progress"),
    ("ok", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --json --out OUT "
           "--no-progress"),
    ("ok", "eval measure --calib dsdome/calib.yaml dsdome/left.png dsdome/right.png --out OUT "
           "--no-progress"),
    ("ok", "eval measure --calib dssurf/calib.yaml dssurf/left.png dssurf/right.png --dense "
           "--depth-range 900,1100 --out OUT --no-progress"),
    ("refuse", "eval measure --calib ds2/calib.yaml ds2/right.png ds2/left.png --out OUT "
               "--no-progress"),
    ("refuse", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/left.png --out OUT "
               "--no-progress"),
    ("refuse", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam2/image.png "
               "ds3/cam1/image.png --out OUT --no-progress"),
    ("refuse", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam0/image.png "
               "ds3/cam2/image.png --out OUT --no-progress"),
    ("refuse", "eval measure --calib dshouse/calib.yaml ds2/left.png ds2/right.png --out OUT "
               "--no-progress"),
    ("bad", "eval measure --calib c1air/camera.yaml ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval measure --calib c4air/calib.yaml ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval measure --calib c4air ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval measure --calib nothere.yaml ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png --out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png nothere.png --out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/manifest.json --out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png p2air/left/00.jpg --out OUT"),
    ("bad", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam1/image.png "
            "--out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --dense --out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --depth-range "
            "1100,900 --dense --out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --methods nosuch "
            "--out OUT"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --out /proc/x"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --out ds3"),
    ("bad", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --encoding nosuch "
            "--out OUT"),
    ("bad", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam1/image.png "
            "ds3/cam2/image.png --dense --depth-range 900,1100 --out OUT"),
    # -- eval score ----------------------------------------------------------------------------
    ("ok", "eval score ds2 --pixels RUN2/points.csv --out OUT"),
    ("ok", "eval score ds2 --points RUN2/points.ply --out OUT"),
    ("ok", "eval score dssurf --points SURF/points.ply --out OUT"),
    ("fail", "eval score ds2 --points SCALED.xyz --out OUT"),
    ("ok", "eval score ds2 --points SCALED.xyz --units m --out OUT"),
    ("bad", "eval score ds2 --points nothere.ply --out OUT"),
    ("bad", "eval score ds2 --points ds2/calib.yaml --out OUT"),
    ("bad", "eval score ds2 --points RUN2/points.ply --method su --out OUT"),
    ("bad", "eval score ds2 --pixels RUN2/points.csv --units m --out OUT"),
    ("bad", "eval score nothere --points RUN2/points.ply --out OUT"),
    ("bad", "eval score p2air --points RUN2/points.ply --out OUT"),
    ("bad", "eval score ds3 --pixels RUN2/points.csv --out OUT"),
    ("bad", "eval score dssurf --pixels RUN2/points.csv --out OUT"),
    ("bad", "eval score ds2 --out OUT"),
    ("bad", "eval score ds2 --points RUN2/points.ply --pixels RUN2/points.csv --out OUT"),
    ("bad", "eval score ds2 --points RUN2/points.ply --gate-mm 0 --out OUT"),
    ("ok", "eval score ds2 --points RUN2/points.ply --out ds2/inside"),  # beside, not over
    # -- eval calibrate ------------------------------------------------------------------------
    ("ok", "eval calibrate b2water --intrinsics c2air/calib.yaml --out OUT --no-progress"),
    ("ok", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --out OUT --no-progress"),
    ("ok", "eval calibrate p2water --intrinsics c2air/calib.yaml --squares 7x6 --square-mm 60 "
           "--out OUT --no-progress"),
    ("ok", "eval calibrate p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
           "--square-mm 60 --out OUT --no-progress"),
    ("ok", "eval calibrate b4water --intrinsics c4air/calib.yaml --out OUT --no-progress"),
    ("ok", "eval calibrate p4air --air --squares 7x6 --square-mm 60 --out OUT --no-progress"),
    ("ok", "eval calibrate b2water --model absorbed --out OUT --no-progress"),
    ("ok", "eval calibrate p2air --air --inner-corners 6x5 --square-mm 60 --out OUT "
           "--no-progress"),
    ("ok", "eval calibrate b4water --intrinsics c4air/calib.yaml --n-water T=12,S=35 --free "
           "distance,normal,n_water --out OUT --no-progress"),
    ("bad", "eval calibrate b2water --out OUT"),
    ("bad", "eval calibrate b2air --intrinsics c2air/calib.yaml --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c1air/camera.yaml --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c4air/calib.yaml --out OUT"),
    ("bad", "eval calibrate b4water --intrinsics c2air/calib.yaml --out OUT"),
    ("bad", "eval calibrate b4water --intrinsics c2air --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics nothere.yaml --out OUT"),
    ("bad", "eval calibrate b4water --intrinsics c4air/calib.yaml --n-water 1.0 --out OUT "
            "--no-progress"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --n-water 0.5 --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --n-water T=99,S=35 "
            "--out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --free nosuch --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --lens k3 --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --squares 7x6 --out OUT"),
    ("bad", "eval calibrate b2air --free distance --out OUT"),
    ("ok", "eval calibrate b2air --air --out OUT"),  # --air agrees with the boards' own word
    ("bad", "eval calibrate b2water --air --out OUT"),
    ("bad", "eval calibrate b4air --lens fisheye --out OUT"),
    ("bad", "eval calibrate p2air --squares 7x6 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p2air --air --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 8x7 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 6x5 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p2air --air --inner-corners 7x6 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p2air/left --air --squares 6x5 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p4air --air --squares 6x5 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm -60 --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --board nosuch --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --marker-mm 30 --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --lens nosuch --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --free distance --out OUT"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --intrinsics "
            "c2air/calib.yaml --out OUT"),
    ("bad", "eval calibrate p2air/left --model absorbed --squares 7x6 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate p4air --model absorbed --squares 7x6 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate b4water --model absorbed --out OUT"),
    ("bad", "eval calibrate b2air --model absorbed --out OUT"),
    ("bad", "eval calibrate nothere --air --squares 7x6 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate ds2/left.png --air --squares 7x6 --square-mm 60 --out OUT"),
    ("bad", "eval calibrate ds2 --out OUT"),
    ("bad", "eval calibrate b2air --out /proc/x --no-progress"),
    ("bad", "eval calibrate b2air --out b4air"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --out OUT --detections"),
    ("bad", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --image-size 640x535 "
            "--out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --port-distance 60,70,80 "
            "--out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --dome-radius 50 --out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --design-port nosuch=3 "
            "--out OUT"),
    ("bad", "eval calibrate b2water --intrinsics c2air/calib.yaml --start-distance 0 --out OUT"),
    ("bad", "eval calibrate p2water --intrinsics c2air/calib.yaml --squares 7x6 --square-mm 60 "
            "--lens k3 --out OUT"),
    ("refuse", "eval calibrate SWAPPED --intrinsics c2air/calib.yaml --squares 7x6 "
               "--square-mm 60 --out OUT --no-progress"),
    ("refuse", "eval calibrate p2water --intrinsics c2air/calib.yaml --squares 7x6 --square-mm 60 "
               "--n-water 1.0 --out OUT --no-progress"),
    ("refuse", "eval calibrate p2air --air --squares 7x6 --square-mm 60 --lens rational "
               "--out OUT --no-progress"),
    ("refuse", "eval calibrate SAME --air --squares 7x6 --square-mm 60 --out OUT --no-progress"),
    ("refuse", "eval calibrate TURNED --air --squares 7x6 --square-mm 60 --out OUT "
               "--no-progress"),
    ("refuse", "eval calibrate TURNED4 --air --squares 7x6 --square-mm 60 --out OUT "
               "--no-progress"),
    # -- eval rectify --------------------------------------------------------------------------
    ("ok", "eval rectify --calib ds2/calib.yaml --distance 1000 ds2/left.png ds2/right.png "
           "--out OUT --no-progress"),
    # a row-aligned pair of a grid: every row ambiguous without a depth window
    ("refuse", "eval measure --calib RECT/calib_rectified.yaml RECT/left_rectified.png "
               "RECT/right_rectified.png --out OUT --no-progress"),
    ("ok", "eval measure --calib RECT/calib_rectified.yaml RECT/left_rectified.png "
           "RECT/right_rectified.png --depth-range 800,1250 --out OUT --no-progress"),
    ("bad", "eval rectify --calib ds3/calib.yaml --distance 1000 ds3/cam0/image.png "
            "ds3/cam1/image.png --out OUT"),
    ("bad", "eval rectify --calib c1air/camera.yaml --distance 1000 ds2/left.png ds2/right.png "
            "--out OUT"),
    ("bad", "eval rectify --calib c2air/calib.yaml --distance 1000 ds2/left.png ds2/right.png "
            "--out OUT"),
    ("bad", "eval rectify --calib ds2/calib.yaml --distance -5 ds2/left.png ds2/right.png "
            "--out OUT"),
    ("bad", "eval rectify --calib ds2/calib.yaml --distance 1000 ds2/left.png nothere.png "
            "--out OUT"),
    ("bad", "eval rectify --calib ds2/calib.yaml --distance 1000 ds2/left.png "
            "p2air/left/00.jpg --out OUT"),
    ("bad", "eval rectify --calib ds2/calib.yaml ds2/left.png ds2/right.png --out OUT"),
    # -- eval track ----------------------------------------------------------------------------
    ("ok", "eval track seq --out OUT --no-progress"),
    ("ok", "eval track seq --lock-on truth --no-absorbed --out OUT --no-progress"),
    ("ok", "eval track seq --no-eccentricity --json --out OUT --no-progress"),
    ("fail", "eval track BLACKSEQ --no-absorbed --out OUT --no-progress"),
    ("bad", "eval track EDITEDSEQ --out OUT --no-progress"),
    ("bad", "eval track ds2 --out OUT"),
    ("bad", "eval track nothere --out OUT"),
    ("bad", "eval track seq --gate 0 --out OUT"),
    ("bad", "eval track seq --no-absorbed --absorbed-calib c2air/calib.yaml --out OUT"),
    ("bad", "eval track seq --absorbed-calib nothere.yaml --out OUT"),
    ("bad", "eval track seq --lock-on nosuch --out OUT"),
    ("bad", "eval track seq --out seq"),
    # -- eval interface ------------------------------------------------------------------------
    ("bad", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --out OUT"),
    ("bad", "eval interface p2water/left --intrinsics c2air/calib.yaml --squares 7x6 "
            "--square-mm 60 --media air,glass:5,water --out OUT"),
    ("bad", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --media air,nosuch:5,water --out OUT"),
    ("bad", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --media air,glass:5,water --free nosuch --out OUT"),
    ("bad", "eval interface p2water --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --media air,glass:5,water --out OUT"),
    ("bad", "eval interface nothere --intrinsics c1air/camera.yaml --squares 7x6 --square-mm 60 "
            "--media air,glass:5,water --out OUT"),
    ("refuse", "eval interface p2air/left --intrinsics c1air/camera.yaml --squares 7x6 "
               "--square-mm 60 --media air,glass:5,water --free normal,thickness:glass "
               "--out OUT --no-progress"),
    # -- eval bench / paper / sweep / render-bench ---------------------------------------------
    ("ok", "eval bench --sizes 1e3 --out OUT.json"),
    ("bad", "eval bench --sizes 0 --out OUT.json"),
    ("bad", "eval bench --sizes abc --out OUT.json"),
    ("bad", "eval bench --out /proc/x.json"),
    ("bad", "eval paper --seed -1 --out OUT"),
    ("bad", "eval paper --out ds2"),
    ("bad", "eval sweep nothere.toml --out OUT"),
    ("bad", "eval sweep pair.xml --out OUT"),
    ("bad", "eval render-bench --parts nosuch --out OUT"),
    # -- the command lines ---------------------------------------------------------------------
    ("ok", "eval --version"),
    ("ok", "synth --version"),
    ("ok", "eval"),
    ("ok", "synth"),
    ("bad", "eval nosuch"),
    ("bad", "synth nosuch"),
    ("bad", "eval run --nosuch-option"),
    ("bad", "eval measure"),
    ("bad", "eval calibrate"),
    ("bad", "synth dataset"),
]



PHOTOS = "--squares 7x6 --square-mm 60"
DETS = "--detections --image-size 640x480"
CIRC = "--board circles --circles 8x6 --pitch-mm 30"
#: One camera's folder, two housings, domes, --lens, --model absorbed, --detections, circle
#: grids, more spoiled inputs, and the shared real photos.
PROBES += [
    # -- one camera's folder -------------------------------------------------------------------
    *[("ok", f"eval calibrate p2air/left --air {PHOTOS} --lens {lens} --out OUT --no-progress")
      for lens in ("standard", "k3", "rational", "fisheye", "radial")],
    ("ok", f"eval calibrate TURNED1 --air {PHOTOS} --out OUT --no-progress"),
    ("ok", f"eval calibrate DUPS1 --air {PHOTOS} --out OUT --no-progress"),
    # a 7-column board is mirror-symmetric: its mirrored photo is a real pose of one camera
    ("ok", f"eval calibrate MIRROR1 --air {PHOTOS} --out OUT --no-progress"),
    ("bad", f"eval calibrate p2air/left --air {PHOTOS} --port-distance 60 --out OUT"),
    ("bad", f"eval calibrate p2water/left --intrinsics c2air/calib.yaml {PHOTOS} --out OUT"),
    ("bad", f"eval calibrate p2water/left --intrinsics c4air/calib.yaml {PHOTOS} --out OUT"),
    ("bad", f"eval calibrate p2water/left --intrinsics c1air {PHOTOS} --out OUT"),
    ("bad", f"eval calibrate p2water/left --intrinsics EMPTY.yaml {PHOTOS} --out OUT"),
    ("bad", f"eval calibrate p2air/left --air {PHOTOS} --stereo-intrinsics refined --out OUT"),
    ("bad", "eval calibrate p2air/left --air --squares 8x7 --square-mm 60 --out OUT"),
    ("ok", f"eval calibrate p2air/left --air {PHOTOS} --out EDITED1 --no-progress"),
    # -- pairs and N cameras: spoiled photos ---------------------------------------------------
    ("refuse", f"eval calibrate TURNW --intrinsics c2air/calib.yaml {PHOTOS} --out OUT "
               f"--no-progress"),
    ("refuse", f"eval calibrate TURN4 --air {PHOTOS} --out OUT --no-progress"),
    ("refuse", f"eval calibrate TURNW4 --intrinsics c4air/calib.yaml {PHOTOS} --out OUT "
               f"--no-progress"),
    ("ok", f"eval calibrate p4water --intrinsics c4air/calib.yaml {PHOTOS} --out OUT "
           f"--no-progress"),
    # one shared port given as a port per camera: own ports of turned cameras cross the others
    ("refuse", f"eval calibrate p4water --intrinsics c4air/calib.yaml {PHOTOS} --port-distance "
               f"100 --out OUT --no-progress"),
    ("bad", f"eval calibrate p4water --intrinsics c4air/calib.yaml {PHOTOS} --port-distance "
            f"60,70 --out OUT"),
    ("bad", f"eval calibrate p4water --intrinsics c2air/calib.yaml {PHOTOS} --out OUT"),
    ("bad", f"eval calibrate p4air --air {PHOTOS} --lens fisheye --out OUT"),
    ("bad", f"eval calibrate p4water --model absorbed {PHOTOS} --out OUT"),
    # -- two housings --------------------------------------------------------------------------
    ("ok", "eval calibrate bhouse --intrinsics c2air/calib.yaml --port-distance 60,70 --out OUT "
           "--no-progress"),
    ("ok", "eval calibrate bhouse --intrinsics c2air/calib.yaml --out OUT --no-progress"),
    ("ok", f"eval calibrate phouse --intrinsics c2air/calib.yaml {PHOTOS} --port-distance 60,70 "
           f"--out OUT --no-progress"),
    ("refuse", f"eval calibrate phouse --intrinsics c2air/calib.yaml {PHOTOS} --out OUT "
               f"--no-progress"),
    ("refuse", f"eval calibrate TURNH --intrinsics c2air/calib.yaml {PHOTOS} --port-distance "
               f"60,70 --out OUT --no-progress"),
    ("bad", "eval calibrate bhouse --intrinsics c2air/calib.yaml --port-distance 60,abc "
            "--out OUT"),
    ("bad", "eval calibrate bhouse --intrinsics c2air/calib.yaml --port-distance 60,-70 "
            "--out OUT"),
    ("bad", "eval calibrate bhouse --intrinsics c2air/calib.yaml --port-distance 60,70 "
            "--dome-radius 50 --out OUT"),
    ("ok", "eval measure --calib dshouse/calib.yaml dshouse/left.png dshouse/right.png "
           "--out OUT --no-progress"),
    ("ok", "synth boards house612.xml --squares 7x6 --square-mm 60 --poses 2 --spp 4 --out OUT "
           "--no-progress"),
    ("ok", "synth check dshouse"),
    # -- domes ---------------------------------------------------------------------------------
    ("ok", "eval calibrate bdome --intrinsics cdomeair/calib.yaml --out OUT --no-progress"),
    ("ok", "eval calibrate bdome --intrinsics bdomeair --out OUT --no-progress"),
    ("bad", "eval calibrate bdome --intrinsics cdomeair/calib.yaml --port-distance 60,70 "
            "--out OUT"),
    ("bad", "eval calibrate bdome --intrinsics cdomeair/calib.yaml --free distance --out OUT"),
    ("bad", "eval calibrate bdome --intrinsics cdomeair/calib.yaml --dome-radius -5 --out OUT"),
    ("bad", "eval calibrate bdome --intrinsics c4air/calib.yaml --out OUT"),
    ("ok", "synth boards dome.xml --squares 7x6 --square-mm 60 --poses 2 --spp 4 --out OUT "
           "--no-progress"),
    ("ok", "synth photos bdome --out OUT"),
    ("bad", "synth scene --port dome --dome-radius 0 --out OUT.xml"),
    ("refuse", "eval measure --calib dsdome/calib.yaml ds2/left.png ds2/right.png --out OUT "
               "--no-progress"),
    # -- --model absorbed ----------------------------------------------------------------------
    ("ok", f"eval calibrate p2water --model absorbed {PHOTOS} --out OUT --no-progress"),
    ("ok", f"eval calibrate p2water --model absorbed {PHOTOS} --stereo-intrinsics refined "
           f"--out OUT --no-progress"),
    # the absorbed pinhole misses the port's rays by more than the default gate
    ("refuse", "eval measure --calib ABS/calib.yaml dspair/left.png dspair/right.png --out OUT "
               "--no-progress"),
    ("ok", "eval measure --calib ABS/calib.yaml dspair/left.png dspair/right.png --gate-mm 3 "
           "--out OUT --no-progress"),
    ("refuse", f"eval calibrate TURNW --model absorbed {PHOTOS} --out OUT --no-progress"),
    ("bad", f"eval calibrate p2water --model absorbed --air {PHOTOS} --out OUT"),
    ("bad", f"eval calibrate p2water --model absorbed --intrinsics c2air/calib.yaml {PHOTOS} "
            f"--out OUT"),
    ("bad", f"eval calibrate p2water --model absorbed {PHOTOS} --port-distance 60,70 --out OUT"),
    # -- your own detections, circle grids -----------------------------------------------------
    ("ok", f"eval calibrate DETS2 {DETS} --air --squares 8x7 --square-mm 30 --out OUT "
           f"--no-progress"),
    ("ok", f"eval calibrate DETS2/left {DETS} --air --squares 8x7 --square-mm 30 --out OUT "
           f"--no-progress"),
    ("ok", f"eval calibrate DETS2 {DETS} --air --squares 8x7 --square-mm 30 --pixel-origin "
           f"colmap --out OUT --no-progress"),
    ("refuse", f"eval calibrate DETSTURN {DETS} --air --squares 8x7 --square-mm 30 --out OUT "
               f"--no-progress"),
    ("bad", f"eval calibrate DETSNAN {DETS} --air --squares 8x7 --square-mm 30 --out OUT"),
    ("bad", f"eval calibrate DETS2 {DETS} --air --squares 7x7 --square-mm 30 --out OUT"),
    ("bad", "eval calibrate DETS2 --detections --air --squares 8x7 --square-mm 30 --out OUT"),
    ("bad", f"eval calibrate DETS2 {DETS} --air --squares 8x7 --square-mm 30 --pixel-origin "
            f"nosuch --out OUT"),
    ("bad", f"eval calibrate p2air {DETS} --air --squares 7x6 --square-mm 60 --out OUT"),
    ("ok", f"eval calibrate CIRCDETS {DETS} --air --lens standard {CIRC} --out OUT "
           f"--no-progress"),
    ("bad", f"eval calibrate CIRCDETS {DETS} --air --board circles --circles 7x6 --pitch-mm 30 "
            f"--out OUT"),
    ("bad", f"eval calibrate CIRCDETS {DETS} --air --board circles --circles 8x6 --out OUT"),
    ("bad", f"eval calibrate CIRCDETS {DETS} --air {CIRC} --circle-mm 40 --out OUT"),
    ("bad", f"eval calibrate CIRCDETS {DETS} --air {CIRC} --square-mm 30 --out OUT"),
    ("ok", "eval calibrate CIRCPH --air --board acircles --circles 4x11 --pitch-mm 20 --out OUT "
           "--no-progress"),
    ("ok", "eval calibrate CIRCPH --air --board acircles --circles 4x11 --pitch-mm 20 "
           "--circle-mm 10 --out OUT --no-progress"),
    ("refuse", "eval calibrate CIRCPH --air --board circles --circles 4x11 --pitch-mm 20 "
               "--out OUT --no-progress"),
    ("refuse", f"eval calibrate CIRCPH --air {PHOTOS} --out OUT --no-progress"),
    # -- measure, score, track, rectify, interface: more ---------------------------------------
    ("refuse", "eval measure --calib ds2/calib.yaml BLACK2/left BLACK2/right --out OUT "
               "--no-progress"),
    ("bad", "eval measure --calib NOPORT.yaml ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval measure --calib TRUNC.yaml ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval measure --calib EMPTY.yaml ds2/left.png ds2/right.png --out OUT"),
    ("ok", "eval measure --calib ds3/calib.yaml ds3/cam0/image.png ds3/cam1/image.png "
           "ds3/cam2/image.png --json --out OUT --no-progress"),
    ("ok", "eval score ds3 --points RUN3/points.ply --out OUT"),
    ("ok", "eval score ds2 --points SHIFTED.xyz --out OUT"),  # a bad score, the shift named
    ("ok", "eval score ds2 --points DOUBLED.xyz --out OUT"),
    ("bad", "eval score ds2 --points RUN2/points.ply --units km --out OUT"),
    ("ok", "eval rectify --calib ds2/calib.yaml --distance 1000 ds2/left.png ds2/right.png "
           "--json --out OUT --no-progress"),
    ("ok", "eval rectify --calib dshouse/calib.yaml --distance 1000 dshouse/left.png "
           "dshouse/right.png --out OUT --no-progress"),
    ("bad", "eval rectify --calib ds2/calib.yaml --distance 1000 --error-distances 900,abc "
            "ds2/left.png ds2/right.png --out OUT"),
    ("bad", "eval rectify --calib ds2/calib.yaml --distance 50 ds2/left.png ds2/right.png "
            "--out OUT"),
    ("bad", "eval rectify --calib ds2/calib.yaml --distance 1000 ds2/left.png ds2/right.png "
            "--out ds3"),
    ("bad", "eval track seq --pixel-sigma -1 --out OUT"),
    ("bad", "eval track seq --absorbed-calib c1air/camera.yaml --out OUT"),
    ("ok", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
           "--square-mm 60 --media air,glass:5,water --out OUT --no-progress"),
    ("bad", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --media air,glass:5,water --free thickness:9 --out OUT"),
    ("bad", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --media air,glass:-5,water --out OUT"),
    ("bad", "eval interface p2water/left --intrinsics c1air/camera.yaml --squares 7x6 "
            "--square-mm 60 --media water --out OUT"),
    # -- synth: more ---------------------------------------------------------------------------
    ("ok", f"synth suite {REPO}/suites/smoke.toml --workers 1 --out OUT --no-progress"),
    ("bad", f"synth suite {REPO}/suites/smoke.toml --workers 0 --out OUT"),
    ("bad", f"synth suite {REPO}/suites/smoke.toml --out ds2"),
    ("ok", "synth boards four.xml --squares 7x6 --square-mm 60 --poses 2 --spp 4 --out OUT "
           "--no-progress"),
    ("ok", "synth boards pair.xml --board charuco --squares 7x6 --square-mm 60 --poses 2 "
           "--spp 4 --out OUT --no-progress"),
    ("ok", "synth render three.xml --spp 4 --out OUT --no-progress"),
    ("ok", "synth scene --size 320 268 --out RESEAL.xml"),
    ("bad", "synth scene --out EDITED.xml"),
    # -- names with spaces and letters beyond ASCII ---------------------------------------------
    ("ok", f"eval calibrate 'fotos ä' --air {PHOTOS} --out 'OUT ü' --no-progress"),
    ("ok", f"eval calibrate 'fotos ä/left' --air {PHOTOS} --out OUT --no-progress"),
    ("ok", "eval measure --calib ds2/calib.yaml ds2/left.png ds2/right.png --out 'OUT ö' "
           "--no-progress"),
    # -- the shared real photos ----------------------------------------------------------------
    ("ok", "eval calibrate REAL/opencv_stereo --air --inner-corners 9x6 --square-mm 30 --out OUT "
           "--no-progress"),
    ("ok", "eval calibrate REAL/opencv_stereo/left --air --squares 10x7 --square-mm 30 "
           "--out OUT --no-progress"),
    ("refuse", "eval calibrate REALTURN --air --squares 10x7 --square-mm 30 --out OUT "
               "--no-progress"),
    ("bad", "eval calibrate REAL/opencv_stereo --air --squares 9x6 --square-mm 30 --out OUT"),
    ("bad", "eval calibrate REAL/opencv_stereo/left --air --squares 9x6 --square-mm 30 "
            "--out OUT"),
    ("ok", "eval calibrate REAL/gopro_inair/photos --air --inner-corners 9x6 --square-mm 9.35 "
           "--lens rational --out OUT --no-progress"),
    ("ok", "eval calibrate REAL/ouc_flat/water --intrinsics couc/camera.yaml --inner-corners 6x5 "
           "--square-mm 33.8 --out OUT --no-progress"),
    ("ok", "eval calibrate REAL/sixer51_dome/water --intrinsics csix/camera.yaml --inner-corners "
           "8x6 --square-mm 30 --dome-radius 43.552 --dome-thickness 3.75 --n-glass 1.495 "
           "--out OUT --no-progress"),
    ("bad", "eval calibrate REAL/ouc_flat/water --intrinsics cstereo/calib.yaml --inner-corners "
            "6x5 --square-mm 33.8 --out OUT"),
    ("bad", "eval calibrate REAL/ouc_flat/water --intrinsics csix/camera.yaml --inner-corners "
            "6x5 --square-mm 33.8 --out OUT"),
    ("refuse", "eval calibrate REAL/agrawal_tank --air --inner-corners 6x5 --square-mm 30 "
            "--out OUT"),
    ("refuse", "eval measure --calib cstereo/calib.yaml REAL/opencv_stereo/left/01.jpg "
            "REAL/opencv_stereo/right/02.jpg --out OUT"),
]
