// dyngi view: the page. Frames arrive as JPEG over the websocket; input goes back as JSON commands
// (protocol: src/dyngi/viewer/server.py). window.dyngiView exposes the page's state to the browser tests.
"use strict";
(function () {
  const $ = (id) => document.getElementById(id);
  const canvas = $("view"), ctx = canvas.getContext("2d");
  const V = window.dyngiView = {
    connected: false, frames: 0, framesBySlot: {}, state: null, stats: {}, errors: [], errorview: null,
    busy: null, split: 0.5,
  };
  const images = {}, lastSeq = {};
  let ws = null, flyMode = false;

  // ---------------------------------------------------------------- connection
  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    ws = new WebSocket(proto + "//" + location.host + "/ws" + location.search);  // ?token=... (or the cookie)
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { V.connected = true; $("conn").textContent = "connected"; };
    ws.onclose = () => {
      V.connected = false; $("conn").textContent = "disconnected: retrying…";
      setTimeout(connect, 1000);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") onJSON(JSON.parse(ev.data)); else onFrame(ev.data);
    };
  }
  function send(msg) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(msg)); }
  V.send = send;

  function onFrame(buf) {
    const dv = new DataView(buf), n = dv.getUint32(0, true);
    const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
    const blob = new Blob([new Uint8Array(buf, 4 + n)], { type: "image/jpeg" });
    const seq = header.seq !== undefined ? header.seq : (header.frame || 0);
    createImageBitmap(blob).then((bmp) => {
      const slot = header.slot;
      if (lastSeq[slot] !== undefined && seq < lastSeq[slot] && !slot.startsWith("err")) { bmp.close(); return; }
      lastSeq[slot] = seq;
      if (images[slot]) images[slot].bmp.close();
      images[slot] = { bmp, header };
      if (canvas.width !== header.w || canvas.height !== header.h) { canvas.width = header.w; canvas.height = header.h; }
      V.frames += 1; V.framesBySlot[slot] = (V.framesBySlot[slot] || 0) + 1;
      draw();
    });
  }

  // ---------------------------------------------------------------- drawing
  function draw() {
    const st = V.state || {}, split = !!st.want_b;
    const useErr = st.error_view && V.errorview && V.errorview.state !== "moving";
    const pick = (s) => (useErr && images["err-" + s]) ? images["err-" + s] : images[s];
    const A = pick("a"), B = split ? pick("b") : null;
    const w = canvas.width, h = canvas.height;
    ctx.fillStyle = "#000"; ctx.fillRect(0, 0, w, h);
    if (A) ctx.drawImage(A.bmp, 0, 0, w, h);
    if (B) {
      const x = Math.round(V.split * w);
      ctx.save(); ctx.beginPath(); ctx.rect(x, 0, w - x, h); ctx.clip();
      ctx.drawImage(B.bmp, 0, 0, w, h); ctx.restore();
      ctx.fillStyle = "#fff"; ctx.fillRect(x - 1, 0, 2, h);
    }
    const lab = (s, im) => s + (im && im.header.flip !== undefined && im.header.flip !== null ?
                                `  FLIP ${im.header.flip.toFixed(4)}` : "");
    $("labelA").textContent = lab(st.spec_a || "", A);
    $("labelB").style.display = split ? "block" : "none";
    $("labelB").textContent = lab(st.want_b || "", B);
  }

  // ---------------------------------------------------------------- messages
  function onJSON(m) {
    if (m.type === "state") { V.state = m; showState(m); draw(); }
    else if (m.type === "stats") { V.stats[m.slot] = m; showStats(); if (m.slot === "a") showTime(m.t); }
    else if (m.type === "busy") showBusy(m);
    else if (m.type === "errorview") {
      V.errorview = m;
      if (m.state === "moving") for (const k of ["err-a", "err-b"]) if (images[k]) { images[k].bmp.close(); delete images[k]; }
      showErrorView(m); draw();
    }
    else if (m.type === "error") showError(m.message);
  }

  function showError(text) {
    V.errors.push(text);
    const d = document.createElement("div");
    d.className = "err"; d.textContent = "error: " + text + "  (click to dismiss)";
    d.onclick = () => d.remove();
    $("errors").appendChild(d);
    while ($("errors").children.length > 3) $("errors").firstChild.remove();
    setTimeout(() => d.remove(), 15000);
  }

  let paramsFor = null;
  function showState(s) {
    $("scene").textContent = `${s.scene} · ${s.res[0]}x${s.res[1]}`;
    const tl = $("techlist");
    const opts = Array.from(new Set([...(s.choices || []), ...(s.techniques || [])]));
    if (tl.children.length !== opts.length) {
      tl.innerHTML = ""; for (const o of opts) { const e = document.createElement("option"); e.value = o; tl.appendChild(e); }
    }
    if (document.activeElement !== $("specA")) $("specA").value = s.spec_a || "";
    if (document.activeElement !== $("specB") && s.want_b) $("specB").value = s.want_b;
    $("play").textContent = s.playing ? "❚❚" : "▶";
    $("scrub").max = String(s.duration || 1);
    if (!s.animated) $("scrub").disabled = true;
    showTime(s.t);
    const sel = $("overlay"), cur = Array.from(sel.options).map((o) => o.value).join();
    if (cur !== s.overlays.join()) {
      sel.innerHTML = ""; for (const o of s.overlays) { const e = document.createElement("option"); e.value = e.textContent = o; sel.appendChild(e); }
    }
    sel.value = s.overlays.includes(s.overlay) ? s.overlay : "none";
    $("errview").checked = !!s.error_view;
    if (!s.error_view) $("evstatus").textContent = "";
    $("exposure").value = String(Math.log2(s.exposure)); $("explabel").textContent = s.exposure.toFixed(2);
    if (paramsFor !== s.spec_a) { paramsFor = s.spec_a; showParams(s.params || []); }
  }

  function showParams(params) {
    const t = $("params"); t.innerHTML = "";
    for (const p of params) {
      const tr = document.createElement("tr"), td0 = document.createElement("td"), td1 = document.createElement("td");
      td0.textContent = p.name; td0.title = p.doc || "";
      let inp;
      if (p.choices) {
        inp = document.createElement("select");
        for (const c of p.choices) { const o = document.createElement("option"); o.value = o.textContent = String(c); inp.appendChild(o); }
        inp.value = String(p.value);
      } else if (p.type === "bool") {
        inp = document.createElement("input"); inp.type = "checkbox"; inp.checked = !!p.value; inp.style.width = "auto";
      } else { inp = document.createElement("input"); inp.type = "text"; inp.value = String(p.value); }
      inp.dataset.name = p.name; inp.dataset.def = String(p.default); inp.title = p.doc || "";
      td1.appendChild(inp); tr.appendChild(td0); tr.appendChild(td1); t.appendChild(tr);
    }
  }

  function paramsSpec() {
    const name = ((V.state && V.state.spec_a) || "").split(":")[0];
    let spec = name;
    for (const inp of $("params").querySelectorAll("input,select")) {
      const v = inp.type === "checkbox" ? String(inp.checked) : inp.value.trim();
      const d = inp.dataset.def;
      const same = v === d || (inp.type === "checkbox" && v === String(d === "true")) ||
                   (v !== "" && d !== "" && !isNaN(Number(v)) && Number(v) === Number(d));
      if (!same) spec += `:${inp.dataset.name}=${v}`;
    }
    return spec;
  }

  function showTime(t) {
    if (t === undefined || t === null) return;
    const dur = (V.state && V.state.duration) || 0;
    if (!scrubbing) $("scrub").value = String(t);
    $("tlabel").textContent = `${t.toFixed(2)} / ${dur.toFixed(2)} s`;
  }

  const fmt = (v, d = 1) => (v === null || v === undefined) ? "–" : Number(v).toFixed(d);
  const fmtRays = (r) => r >= 1e6 ? (r / 1e6).toFixed(2) + "M" : r >= 1e3 ? (r / 1e3).toFixed(1) + "k" : String(r);
  function showStats() {
    let html = "";
    for (const slot of ["a", "b"]) {
      const m = V.stats[slot];
      if (!m || (slot === "b" && !(V.state && V.state.want_b))) continue;
      const ms = (m.stats && m.stats.ms) || {}, rays = (m.stats && m.stats.rays) || {};
      const stages = Array.from(new Set([...Object.keys(ms), ...Object.keys(rays)]));
      html += `<table data-slot="${slot}"><tr><th>${slot.toUpperCase()}: ${escapeHtml(m.spec)}</th><th>ms</th><th>rays</th></tr>`;
      for (const k of stages) html += `<tr class="stage"><td>${escapeHtml(k)}</td><td>${fmt(ms[k])}</td><td>${rays[k] !== undefined ? fmtRays(rays[k]) : ""}</td></tr>`;
      const tr = Object.values(rays).reduce((a, b) => a + b, 0);
      html += `<tr><td><b>frame ${m.frame}</b></td><td><b>${fmt(m.wall_ms)}</b></td><td><b>${fmtRays(tr)}</b></td></tr>`;
      html += `<tr class="dim"><td>frames/s</td><td>${fmt(m.fps)}</td><td></td></tr>`;
      if (m.first_frame_ms) html += `<tr class="dim"><td>first frame (compile)</td><td>${fmt(m.first_frame_ms, 0)}</td><td></td></tr>`;
      html += `<tr class="dim"><td>tonemap + JPEG</td><td>${fmt(m.encode_ms)}</td><td></td></tr>`;
      if (m.overlay_ms) html += `<tr class="dim"><td>overlay</td><td>${fmt(m.overlay_ms)}</td><td></td></tr>`;
      if (m.nonfinite_pixels) html += `<tr><td style="color:var(--bad)">NaN/Inf pixels</td><td>${m.nonfinite_pixels}</td><td></td></tr>`;
      html += "</table><br>";
    }
    $("stats").innerHTML = html;
  }
  function escapeHtml(s) { return String(s).replace(/[&<>"]/g, (c) => ({ "&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;" })[c]); }

  function showBusy(m) {
    V.busy = m.busy ? m : null;
    $("busy").style.display = m.busy ? "block" : "none";
    if (!m.busy) return;
    const el = m.elapsed_ms / 1000;
    const exp = m.expected_ms ? ` of ~${(m.expected_ms / 1000).toFixed(1)} s` : "";
    $("busytext").textContent = `${m.what} ${m.spec} (frame ${m.frame}): ${el.toFixed(1)} s${exp}`;
    const frac = m.expected_ms ? Math.min(0.98, m.elapsed_ms / m.expected_ms) : (1 - Math.exp(-el / 5));
    $("busybar").style.width = (100 * frac).toFixed(0) + "%";
  }

  function showErrorView(m) {
    let t = m.text || "";
    if (m.state === "ready" && m.flip) t = "FLIP " + Object.entries(m.flip).map(([k, v]) => `${k.toUpperCase()} ${v.toFixed(4)}`).join(", ") + " · " + t;
    $("evstatus").textContent = t;
  }

  // ---------------------------------------------------------------- controls
  $("applyA").onclick = () => send({ type: "technique", slot: "a", spec: $("specA").value });
  $("specA").onkeydown = (e) => { if (e.key === "Enter") $("applyA").click(); e.stopPropagation(); };
  $("applyParams").onclick = () => send({ type: "technique", slot: "a", spec: paramsSpec() });
  $("applyB").onclick = () => send({ type: "technique", slot: "b", spec: $("specB").value });
  $("specB").onkeydown = (e) => { if (e.key === "Enter") $("applyB").click(); e.stopPropagation(); };
  $("offB").onclick = () => { send({ type: "technique", slot: "b", spec: null }); delete images.b; };
  $("overlay").onchange = () => send({ type: "overlay", name: $("overlay").value });
  $("errview").onchange = () => send({ type: "error_view", on: $("errview").checked });
  $("exposure").oninput = () => send({ type: "exposure", value: Math.pow(2, Number($("exposure").value)) });
  $("flymode").onchange = () => { flyMode = $("flymode").checked; };
  $("play").onclick = () => send({ type: "play", playing: !(V.state && V.state.playing) });
  let scrubbing = false;
  $("scrub").oninput = () => { scrubbing = true; send({ type: "seek", t: Number($("scrub").value) }); };
  $("scrub").onchange = () => { scrubbing = false; };

  // mouse: orbit / look / pan / zoom / split divider; moves are coalesced to one message per 33 ms
  let drag = null, acc = { dx: 0, dy: 0 }, lastSend = 0;
  function flushDrag(force) {
    const now = performance.now();
    if (!drag || (!force && now - lastSend < 33) || (acc.dx === 0 && acc.dy === 0)) return;
    send({ type: "camera", op: drag.op, dx: acc.dx, dy: acc.dy, height: canvas.clientHeight });
    acc = { dx: 0, dy: 0 }; lastSend = now;
  }
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => {
    canvas.focus();
    const r = canvas.getBoundingClientRect(), split = V.state && V.state.want_b;
    if (split && Math.abs(e.clientX - r.left - V.split * r.width) < 8) drag = { op: "divider" };
    else if (e.button === 2 || e.shiftKey) drag = { op: "pan" };
    else drag = { op: flyMode ? "look" : "orbit" };
    canvas.setPointerCapture(e.pointerId); canvas.classList.add("dragging");
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    if (drag.op === "divider") {
      const r = canvas.getBoundingClientRect();
      V.split = Math.min(1, Math.max(0, (e.clientX - r.left) / r.width)); draw(); return;
    }
    acc.dx += e.movementX; acc.dy += e.movementY; flushDrag(false);
  });
  const endDrag = () => { flushDrag(true); drag = null; canvas.classList.remove("dragging"); };
  canvas.addEventListener("pointerup", endDrag);
  canvas.addEventListener("pointercancel", endDrag);
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    send({ type: "camera", op: "zoom", steps: Math.max(-5, Math.min(5, e.deltaY / 100)) });
  }, { passive: false });

  // keyboard: fly (held keys, sent every 50 ms with the time they were held), look, reset, play
  const held = new Set();
  let shift = false;
  const flyKeys = { KeyW: [1, 0, 0], KeyS: [-1, 0, 0], KeyD: [0, 1, 0], KeyA: [0, -1, 0], KeyE: [0, 0, 1], KeyQ: [0, 0, -1] };
  const lookKeys = { ArrowLeft: [-1, 0], ArrowRight: [1, 0], ArrowUp: [0, -1], ArrowDown: [0, 1] };
  document.addEventListener("keydown", (e) => {
    shift = e.shiftKey;
    if (e.target.tagName === "INPUT" && e.target.type === "text") return;
    if (flyKeys[e.code] || lookKeys[e.code]) { held.add(e.code); e.preventDefault(); }
    else if (e.code === "Space") { $("play").click(); e.preventDefault(); }
    else if (e.code === "KeyR") send({ type: "camera", op: "reset" });
    else if (e.code === "KeyF") { flyMode = !flyMode; $("flymode").checked = flyMode; }
  });
  document.addEventListener("keyup", (e) => { shift = e.shiftKey; held.delete(e.code); });
  window.addEventListener("blur", () => held.clear());
  let lastKey = performance.now();
  setInterval(() => {
    const now = performance.now(), dt = Math.min(0.2, (now - lastKey) / 1000); lastKey = now;
    if (!held.size) return;
    let f = 0, r = 0, u = 0, lx = 0, ly = 0;
    for (const k of held) {
      if (flyKeys[k]) { f += flyKeys[k][0]; r += flyKeys[k][1]; u += flyKeys[k][2]; }
      if (lookKeys[k]) { lx += lookKeys[k][0]; ly += lookKeys[k][1]; }
    }
    if (f || r || u) send({ type: "camera", op: "fly", forward: f, right: r, up: u, dt, fast: shift });
    if (lx || ly) send({ type: "camera", op: "look", dx: lx * 400 * dt, dy: ly * 400 * dt });
  }, 50);

  connect();
})();
