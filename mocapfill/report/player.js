// mocapfill report player: the markers of a capture in 3-D on a <canvas>, frame by frame.
// Data: the JSON block beside this script (see mocapfill/report/player.py for its layout). No library, no network.
(function () {
  "use strict";
  var section = document.getElementById("player");
  if (!section) return;
  var P = JSON.parse(section.querySelector("script.player-data").textContent);
  var view = section.querySelector("canvas.view"), strip = section.querySelector("canvas.strip");
  var slider = section.querySelector(".slider"), playButton = section.querySelector(".play");
  var speedSelect = section.querySelector(".speed"), frameText = section.querySelector(".frame");
  var pickText = section.querySelector(".pick"), namesBox = section.querySelector(".names");
  var followBox = section.querySelector(".follow");
  var C = P.colours;
  P.gaps = P.gaps.map(function (g) {  // [marker, first, last, status, method, mean std, max std, reason]
    function text(i) { return i < 0 ? null : P.texts[i]; }
    return [g[0], g[1], g[2], text(g[3]), text(g[4]), g[5], g[6], text(g[7])];
  });

  function bytes(text) {
    var bin = atob(text), out = new Uint8Array(bin.length);
    for (var i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out;
  }
  var q = new Int16Array(bytes(P.positions).buffer);  // little-endian, as written
  var status = bytes(P.status);
  var M = P.labels.length, F = P.n_shown, STRIDE = P.stride, RATE = P.rate > 0 ? P.rate : 1;
  var K = P.up[0], S = P.up[1], K1 = (K + 1) % 3, K2 = (K + 2) % 3;

  // Scene coordinates: z up, (x, y, z) right-handed, whatever the file's convention.
  function scene(w) { return [w[K1], S * w[K2], S * w[K]]; }
  function world(f, m) {
    var i = (f * M + m) * 3;
    if (q[i] === -32768) return null;
    return [P.origin[0] + (q[i] + 32767) * P.scale, P.origin[1] + (q[i + 1] + 32767) * P.scale,
            P.origin[2] + (q[i + 2] + 32767) * P.scale];
  }
  function stdOf(code) {
    if (code < 3) return NaN;
    var r = (code - 3) / P.std_levels;
    return P.std_max * r * r;
  }

  // Bounds of the scene for the camera and the ground grid.
  var lo = scene(P.box[0]), hi = scene(P.box[1]);
  for (var a = 0; a < 3; a++) { if (lo[a] > hi[a]) { var t = lo[a]; lo[a] = hi[a]; hi[a] = t; } }
  var floorZ = S * P.floor;
  var centre = [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (Math.max(lo[2], floorZ) + hi[2]) / 2];
  var diag = Math.max(Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]), P.grid);
  var grid = P.grid;
  while (((hi[0] - lo[0]) / grid + (hi[1] - lo[1]) / grid) > 80) grid *= 2;
  var gx0 = Math.floor(lo[0] / grid - 1) * grid, gx1 = Math.ceil(hi[0] / grid + 1) * grid;
  var gy0 = Math.floor(lo[1] / grid - 1) * grid, gy1 = Math.ceil(hi[1] / grid + 1) * grid;

  // Where the subject is in each shown frame: the centroid of its markers, held over frames where none is seen and
  // smoothed over half a second, so that the following camera glides instead of jumping when markers drop out.
  var track = new Float64Array(F * 3), have = false, last = centre.slice();
  for (var f0 = 0; f0 < F; f0++) {
    var sum = [0, 0, 0], n = 0;
    for (var m0 = 0; m0 < M; m0++) {
      var w0 = status[f0 * M + m0] === 1 ? null : world(f0, m0);
      if (!w0) continue;
      var s0 = scene(w0);
      sum[0] += s0[0]; sum[1] += s0[1]; sum[2] += s0[2]; n++;
    }
    if (n) { last = [sum[0] / n, sum[1] / n, sum[2] / n]; have = true; }
    track[3 * f0] = last[0]; track[3 * f0 + 1] = last[1]; track[3 * f0 + 2] = last[2];
  }
  var half = Math.max(1, Math.round(0.25 * RATE / STRIDE)), smooth = new Float64Array(F * 3);
  for (var ax = 0; ax < 3; ax++) {  // moving average by a running sum
    var run = 0, cnt = 0;
    for (var f1 = 0; f1 < F + half; f1++) {
      if (f1 < F) { run += track[3 * f1 + ax]; cnt++; }
      if (f1 - 2 * half - 1 >= 0) { run -= track[3 * (f1 - 2 * half - 1) + ax]; cnt--; }
      var c1 = f1 - half;
      if (c1 >= 0 && c1 < F) smooth[3 * c1 + ax] = run / cnt;
    }
  }
  var body = P.body > 0 ? P.body : diag;
  var HOME = {az: -Math.PI / 3, el: 0.3, dist: Math.min(1.9 * diag, 2.0 * body), target: centre.slice()};
  var cam = {az: HOME.az, el: HOME.el, dist: HOME.dist, target: HOME.target.slice()};
  var frame = 0, selected = -1, playing = false, clock = 0, lastTick = 0;
  var drawn = 0, basis = null, shownPoints = [];

  // Gaps, by the shown frame where each one starts (for the gap buttons and the click info).
  var gapStops = P.gaps.map(function (g, i) {
    return {shown: Math.min(Math.ceil(g[1] / STRIDE), F - 1), gap: i};
  }).sort(function (x, y) { return x.shown - y.shown; });
  var rejectedAt = {};
  P.rejected.forEach(function (r) { (rejectedAt[r[0]] = rejectedAt[r[0]] || []).push(r); });

  function setBasis(width, height) {
    var ce = Math.cos(cam.el), se = Math.sin(cam.el), ca = Math.cos(cam.az), sa = Math.sin(cam.az);
    var eye = [cam.target[0] + cam.dist * ce * ca, cam.target[1] + cam.dist * ce * sa, cam.target[2] + cam.dist * se];
    var fwd = [-ce * ca, -ce * sa, -se];
    var right = [-sa, ca, 0];                                  // fwd x z, normalised
    var up = [right[1] * fwd[2] - right[2] * fwd[1], right[2] * fwd[0] - right[0] * fwd[2],
              right[0] * fwd[1] - right[1] * fwd[0]];
    basis = {eye: eye, fwd: fwd, right: right, up: up, focal: 0.5 * height / Math.tan(Math.PI / 8),
             cx: width / 2, cy: height / 2, near: diag * 1e-3};
  }
  function project(p) {
    var b = basis, dx = p[0] - b.eye[0], dy = p[1] - b.eye[1], dz = p[2] - b.eye[2];
    var z = dx * b.fwd[0] + dy * b.fwd[1] + dz * b.fwd[2];
    if (z < b.near) return null;
    var x = dx * b.right[0] + dy * b.right[1] + dz * b.right[2];
    var y = dx * b.up[0] + dy * b.up[1] + dz * b.up[2];
    return [b.cx + b.focal * x / z, b.cy - b.focal * y / z, z];
  }
  function line(ctx, p, r) {  // a 3-D segment, in pieces so that parts behind the camera drop out
    var n = 8, prev = null;
    for (var i = 0; i <= n; i++) {
      var u = i / n, s = project([p[0] + (r[0] - p[0]) * u, p[1] + (r[1] - p[1]) * u, p[2] + (r[2] - p[2]) * u]);
      if (s && prev) { ctx.moveTo(prev[0], prev[1]); ctx.lineTo(s[0], s[1]); }
      prev = s;
    }
  }

  function gapAt(m, orig) {
    for (var i = 0; i < P.gaps.length; i++) {
      var g = P.gaps[i];
      if (g[0] === m && g[1] <= orig && orig <= g[2]) return g;
    }
    return null;
  }
  var MM = {mm: 1, cm: 10, m: 1000}[P.units] || 1, LEN = MM === 1 ? P.units : "mm";
  function fmt(x) {  // a length of the file, shown in mm when the file is in cm or m
    if (x == null || isNaN(x)) return "\u2013";
    x *= MM;
    return (Math.abs(x) >= 100 ? x.toFixed(0) : x.toPrecision(2)) + " " + LEN;
  }

  function describe() {
    if (selected < 0) {
      pickText.textContent = "Click a marker for its name" + (P.fill ? " and, when filled, how its gap was filled." : ".");
      return;
    }
    var orig = frame * STRIDE, code = status[frame * M + selected], label = P.labels[selected];
    var text = label + " at frame " + (P.first_frame + orig) + ": ";
    var g = gapAt(selected, orig);
    if (code === 1) text += "missing here (not drawn)";
    else if (code === 0) text += "observed";
    else {
      text += "filled";
      var s = stdOf(code);
      text += isNaN(s) ? " (no uncertainty for this sample)" : ", uncertainty here " + fmt(s) + " (1 std)";
    }
    if (g) {
      text += ". Gap frames " + (P.first_frame + g[1]) + "\u2013" + (P.first_frame + g[2]) + " (" + (g[2] - g[1] + 1) +
              " frames)";
      if (g[3] && g[3] !== "missing") text += ", " + g[3];
      if (g[4]) text += ", filled by " + g[4];
      if (g[5] != null) text += ", uncertainty mean " + fmt(g[5]) + " / max " + fmt(g[6]);
      if (g[7]) text += " (" + g[7] + ")";
    }
    (rejectedAt[frame] || []).forEach(function (r) {
      if (r[1] === selected) text += ". Outlier rejected here: its original position is the \u2715";
    });
    pickText.textContent = text + ".";
  }

  function draw() {
    var dpr = window.devicePixelRatio || 1;
    var w = Math.max(1, Math.round(view.clientWidth * dpr)), h = Math.max(1, Math.round(view.clientHeight * dpr));
    if (view.width !== w || view.height !== h) { view.width = w; view.height = h; }
    var ctx = view.getContext("2d");
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#f7f8fa";
    ctx.fillRect(0, 0, w, h);
    setBasis(w, h);
    ctx.lineWidth = dpr;
    if (followBox.checked && F) cam.target = [smooth[3 * frame], smooth[3 * frame + 1], smooth[3 * frame + 2]];

    // Ground grid at the floor.
    ctx.strokeStyle = "#dde1e6";
    ctx.beginPath();
    for (var gx = gx0; gx <= gx1 + 1e-9; gx += grid) line(ctx, [gx, gy0, floorZ], [gx, gy1, floorZ]);
    for (var gy = gy0; gy <= gy1 + 1e-9; gy += grid) line(ctx, [gx0, gy, floorZ], [gx1, gy, floorZ]);
    ctx.stroke();

    // The file's axes in the corner, turning with the view (the vertical one says "up").
    var ox = 40 * dpr, oy = h - 40 * dpr, len = 28 * dpr;
    ctx.font = (11 * dpr) + "px sans-serif";
    for (var ax = 0; ax < 3; ax++) {
      var unit = [0, 0, 0];
      unit[ax] = 1;
      var d3 = scene(unit), b = basis;
      var sx = d3[0] * b.right[0] + d3[1] * b.right[1] + d3[2] * b.right[2];
      var sy = d3[0] * b.up[0] + d3[1] * b.up[1] + d3[2] * b.up[2];
      ctx.strokeStyle = ctx.fillStyle = C.axes[ax];
      ctx.lineWidth = 2 * dpr;
      ctx.beginPath(); ctx.moveTo(ox, oy); ctx.lineTo(ox + len * sx, oy - len * sy); ctx.stroke();
      ctx.fillText("XYZ"[ax] + (ax === K ? (S > 0 ? " up" : " down") : ""), ox + (len + 4 * dpr) * sx - 3 * dpr,
                   oy - (len + 4 * dpr) * sy + 4 * dpr);
    }

    // Markers of this frame.
    var pts = new Array(M);
    shownPoints = [];
    for (var m = 0; m < M && F > 0; m++) {
      var code = status[frame * M + m];
      if (code === 1) continue;
      var wpos = world(frame, m);
      if (!wpos) continue;
      var sp = scene(wpos), pr = project(sp);
      if (!pr) continue;
      pts[m] = {m: m, x: pr[0], y: pr[1], z: pr[2], code: code, p: sp};
      shownPoints.push(pts[m]);
    }
    ctx.lineWidth = 1.5 * dpr;
    P.bones.forEach(function (b) {
      var u = pts[b[0]], v = pts[b[1]];
      if (!u || !v) return;
      ctx.strokeStyle = (u.code >= 2 || v.code >= 2) ? C.band : C.bone;
      ctx.beginPath(); ctx.moveTo(u.x, u.y); ctx.lineTo(v.x, v.y); ctx.stroke();
    });
    var order = shownPoints.slice().sort(function (u, v) { return v.z - u.z; });
    var radius = 3.5 * dpr;
    order.forEach(function (pt) {
      if (pt.code >= 2) {
        var s = stdOf(pt.code);
        if (!isNaN(s)) {  // the halo: one standard deviation, at the marker's depth
          var rr = Math.max(radius + dpr, basis.focal * s / pt.z);
          ctx.fillStyle = C.band;
          ctx.globalAlpha = 0.28;
          ctx.beginPath(); ctx.arc(pt.x, pt.y, rr, 0, 2 * Math.PI); ctx.fill();
          ctx.globalAlpha = 0.8;
          ctx.strokeStyle = C.band;
          ctx.lineWidth = dpr;
          ctx.stroke();
          ctx.globalAlpha = 1;
        }
      }
      ctx.fillStyle = pt.code >= 2 ? C.filled : C.observed;
      ctx.beginPath(); ctx.arc(pt.x, pt.y, pt.code >= 2 ? radius * 1.25 : radius, 0, 2 * Math.PI); ctx.fill();
    });
    (rejectedAt[frame] || []).forEach(function (r) {
      var pr = project(scene([r[2], r[3], r[4]]));
      if (!pr) return;
      var d = 5 * dpr, now = pts[r[1]];
      ctx.strokeStyle = C.rejected;
      if (now) {  // from the rejected original to what the fill put there
        ctx.lineWidth = dpr;
        ctx.setLineDash([3 * dpr, 3 * dpr]);
        ctx.beginPath(); ctx.moveTo(pr[0], pr[1]); ctx.lineTo(now.x, now.y); ctx.stroke();
        ctx.setLineDash([]);
      }
      ctx.lineWidth = 2 * dpr;
      ctx.beginPath();
      ctx.moveTo(pr[0] - d, pr[1] - d); ctx.lineTo(pr[0] + d, pr[1] + d);
      ctx.moveTo(pr[0] - d, pr[1] + d); ctx.lineTo(pr[0] + d, pr[1] - d);
      ctx.stroke();
    });
    ctx.font = (10 * dpr) + "px sans-serif";
    ctx.fillStyle = "#333";
    if (namesBox.checked) {
      shownPoints.forEach(function (pt) { ctx.fillText(P.labels[pt.m], pt.x + 5 * dpr, pt.y - 4 * dpr); });
    }
    if (selected >= 0 && pts[selected]) {
      var ps = pts[selected];
      ctx.strokeStyle = C.selected;
      ctx.lineWidth = 2 * dpr;
      ctx.beginPath(); ctx.arc(ps.x, ps.y, radius + 4 * dpr, 0, 2 * Math.PI); ctx.stroke();
      ctx.fillStyle = C.selected;
      ctx.font = "bold " + (12 * dpr) + "px sans-serif";
      ctx.fillText(P.labels[selected], ps.x + 9 * dpr, ps.y - 7 * dpr);
    }
    drawn = shownPoints.length;

    var orig = frame * STRIDE, filledNow = 0;
    shownPoints.forEach(function (pt) { if (pt.code >= 2) filledNow++; });
    frameText.textContent = "frame " + (P.first_frame + orig) + " of " + (P.first_frame + P.n_frames - 1) + " \u00b7 " +
      (orig / RATE).toFixed(2) + " s \u00b7 " + drawn + "/" + M + " markers" +
      (P.fill ? " (" + filledNow + " filled)" : "");
    slider.value = String(frame);
    drawStrip();
    describe();
  }

  // The strip under the view: per column, how many markers are filled (fill colour) or missing (grey).
  var stripCounts = null;
  function drawStrip() {
    var dpr = window.devicePixelRatio || 1;
    var w = Math.max(1, Math.round(strip.clientWidth * dpr)), h = Math.max(1, Math.round(strip.clientHeight * dpr));
    if (strip.width !== w || strip.height !== h) { strip.width = w; strip.height = h; stripCounts = null; }
    var ctx = strip.getContext("2d");
    if (!stripCounts) {
      stripCounts = [];
      for (var x = 0; x < w; x++) {
        var f0 = Math.floor(x * F / w), f1 = Math.max(f0 + 1, Math.floor((x + 1) * F / w)), fil = 0, mis = 0;
        for (var f = f0; f < f1 && f < F; f++) {
          for (var m = 0; m < M; m++) { var c = status[f * M + m]; if (c === 1) mis++; else if (c >= 2) fil++; }
        }
        var n = Math.max(1, (f1 - f0) * M);
        stripCounts.push([fil / n, mis / n]);
      }
    }
    ctx.fillStyle = "#eef0f2";
    ctx.fillRect(0, 0, w, h);
    for (var i = 0; i < stripCounts.length; i++) {
      var fh = Math.ceil(stripCounts[i][0] * h), mh = Math.ceil(stripCounts[i][1] * h);
      // at least a third of the strip: one marker's short gap must still be seen
      if (fh) { fh = Math.max(fh, Math.ceil(h / 3)); ctx.fillStyle = C.filled; ctx.fillRect(i, h - fh, 1, fh); }
      if (mh) { mh = Math.max(mh, Math.ceil(h / 3)); ctx.fillStyle = "#9a9a9a"; ctx.fillRect(i, Math.max(0, h - fh - mh), 1, mh); }
    }
    ctx.fillStyle = "#2b6cb0";
    ctx.fillRect(Math.round((frame + 0.5) * w / Math.max(F, 1)) - dpr, 0, 2 * dpr, h);
  }

  function show(f) {
    frame = Math.max(0, Math.min(F - 1, f | 0));
    clock = frame * STRIDE / RATE;
    draw();
  }
  function jump(next) {
    var target = null;
    if (next) {
      for (var i = 0; i < gapStops.length; i++) if (gapStops[i].shown > frame) { target = gapStops[i]; break; }
    } else {
      for (var j = gapStops.length - 1; j >= 0; j--) if (gapStops[j].shown < frame) { target = gapStops[j]; break; }
    }
    if (!target) return;
    selected = P.gaps[target.gap][0];
    setPlaying(false);
    show(target.shown);
  }
  function setPlaying(on) {
    playing = on && F > 1;
    playButton.textContent = playing ? "Pause" : "Play";
    if (playing) { lastTick = 0; requestAnimationFrame(tick); }
  }
  function tick(now) {
    if (!playing) return;
    if (lastTick) {
      clock += (now - lastTick) / 1000 * parseFloat(speedSelect.value);
      var f = Math.floor(clock * RATE / STRIDE);
      if (f >= F) { clock = 0; f = 0; }
      if (f !== frame) { frame = f; draw(); }
    }
    lastTick = now;
    requestAnimationFrame(tick);
  }

  slider.addEventListener("input", function () { show(parseInt(slider.value, 10)); });
  playButton.addEventListener("click", function () { setPlaying(!playing); });
  section.querySelector(".prev-gap").addEventListener("click", function () { jump(false); });
  section.querySelector(".next-gap").addEventListener("click", function () { jump(true); });
  section.querySelector(".reset").addEventListener("click", function () {
    cam.az = HOME.az; cam.el = HOME.el; home(); draw();
  });
  namesBox.addEventListener("change", draw);
  function home() {  // following: a few body sizes away; not following: the whole capture volume in view
    cam.target = HOME.target.slice();
    cam.dist = followBox.checked ? HOME.dist : Math.max(HOME.dist, 1.9 * diag);
  }
  followBox.addEventListener("change", function () { home(); draw(); });
  strip.addEventListener("click", function (e) {
    var r = strip.getBoundingClientRect();
    show(Math.floor((e.clientX - r.left) / r.width * F));
  });
  var drag = null;
  view.addEventListener("pointerdown", function (e) {
    drag = {x: e.clientX, y: e.clientY, az: cam.az, el: cam.el, moved: false};
    view.focus({preventScroll: true});
    view.setPointerCapture(e.pointerId);
  });
  view.addEventListener("pointermove", function (e) {
    if (!drag) return;
    var dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 3) drag.moved = true;
    if (!drag.moved) return;
    cam.az = drag.az - dx * 0.008;
    cam.el = Math.max(-1.5, Math.min(1.5, drag.el + dy * 0.008));
    draw();
  });
  view.addEventListener("pointerup", function (e) {
    if (drag && !drag.moved) {
      var r = view.getBoundingClientRect(), dpr = view.width / Math.max(r.width, 1);
      var x = (e.clientX - r.left) * dpr, y = (e.clientY - r.top) * dpr, best = -1, bestD = 12 * dpr;
      shownPoints.forEach(function (pt) {
        var d = Math.hypot(pt.x - x, pt.y - y);
        if (d < bestD) { bestD = d; best = pt.m; }
      });
      selected = best;
      draw();
    }
    drag = null;
  });
  view.addEventListener("wheel", function (e) {
    e.preventDefault();
    cam.dist = Math.max(diag * 0.05, Math.min(diag * 20, cam.dist * Math.exp(e.deltaY * 0.001)));
    draw();
  }, {passive: false});
  window.addEventListener("resize", draw);
  view.addEventListener("keydown", function (e) {  // with the view focused: space plays, arrows step
    if (e.key === " ") { setPlaying(!playing); e.preventDefault(); }
    else if (e.key === "ArrowRight") { setPlaying(false); show(frame + 1); e.preventDefault(); }
    else if (e.key === "ArrowLeft") { setPlaying(false); show(frame - 1); e.preventDefault(); }
  });

  // #player-frame=N&marker=NAME opens the player at a frame (file numbering) with a marker picked.
  var hash = decodeURIComponent((location.hash || "").slice(1)), opts = {};
  hash.split("&").forEach(function (kv) { var i = kv.indexOf("="); if (i > 0) opts[kv.slice(0, i)] = kv.slice(i + 1); });
  if (opts.marker) selected = P.labels.indexOf(opts.marker);
  show(opts["player-frame"] ? Math.round((parseInt(opts["player-frame"], 10) - P.first_frame) / STRIDE) : 0);

  // #player-selftest: move the slider as a user would and record what was drawn (read back by the test suite).
  function inked() {
    var ctx = view.getContext("2d"), img = ctx.getImageData(0, 0, view.width, view.height).data, n = 0;
    for (var i = 0; i < img.length; i += 4) {  // the observed markers' dark grey, nothing else on the canvas has it
      var r = img[i], g = img[i + 1], b = img[i + 2];
      if (r < 120 && Math.abs(r - g) < 16 && Math.abs(g - b) < 16 && img[i + 3] > 200) n++;
    }
    return n;
  }
  if (hash.indexOf("player-selftest") === 0) {
    var state = {frames: [], drawn: [], inked: [], labels: []};
    function record() {
      state.frames.push(frame); state.drawn.push(drawn); state.inked.push(inked());
      state.labels.push(frameText.textContent);
    }
    record();
    slider.value = String(Math.floor((F - 1) / 2));
    slider.dispatchEvent(new Event("input", {bubbles: true}));
    record();
    state.n_shown = F;
    // a click on a marker names it
    var target = shownPoints[0];
    if (target) {
      var r = view.getBoundingClientRect(), k = r.width / view.width;
      var at = {clientX: r.left + target.x * k, clientY: r.top + target.y * k, pointerId: 1, bubbles: true};
      view.dispatchEvent(new PointerEvent("pointerdown", at));
      view.dispatchEvent(new PointerEvent("pointerup", at));
      state.picked = P.labels[target.m];
      state.pick_text = pickText.textContent;
    }
    state.errors = window.__playerErrors || [];
    document.documentElement.setAttribute("data-player-selftest", JSON.stringify(state));
    // play for a moment: the frame must move on by itself
    var before = frame;
    playButton.click();
    setTimeout(function () {
      state.played = [before, frame, playButton.textContent];
      playButton.click();
      state.errors = window.__playerErrors || [];
      document.documentElement.setAttribute("data-player-selftest", JSON.stringify(state));
    }, 1000);
  }
})();
