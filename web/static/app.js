// SPDX-License-Identifier: MIT
// hapsim-web page: live surface, tools, forces, status, commands and the mouse probe.
// Wire format: docs/client.md "hapsim-web". three.js r111 (Debian libjs-three): buffer
// geometries are the *BufferGeometry classes.
'use strict';
(function () {
  const $ = (id) => document.getElementById(id);
  const glCanvas = $('gl'), overlay = $('overlay'), ctx2d = overlay.getContext('2d');

  // ---------------------------------------------------------------- three.js scene
  const renderer = new THREE.WebGLRenderer({ canvas: glCanvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setClearColor(0x1d2128);
  const scene = new THREE.Scene();
  const camera = new THREE.PerspectiveCamera(35, 1, 0.001, 100);
  camera.position.set(0.3, 0.25, 0.35);
  const controls = new THREE.OrbitControls(camera, glCanvas);
  controls.enableDamping = false;
  controls.screenSpacePanning = true;
  scene.add(new THREE.HemisphereLight(0xffffff, 0x404050, 0.55));
  const headlight = new THREE.DirectionalLight(0xffffff, 0.65);
  camera.add(headlight);
  scene.add(camera);

  const S = {                // everything the page knows (also read by the end-to-end test)
    topo: null,              // {version, nVis, nTri, rest: Float32Array, tri: Uint32Array}
    frame: null,             // {version, simTime, simStep}
    frames: 0,
    maxDisp: 0,              // m, largest displacement magnitude in the shown frame
    range: 1e-3,             // m, colour range (red)
    rangeSetAt: 0,
    status: null,
    tools: [],
    models: [],
    mouse: { active: false, dev: -1 },
    acks: [],
    history: [],             // [{t, f: {dev: |F|}}]
    session: 0,
  };
  window.hapsim = { S: S };

  let surf = null, restMesh = null, restLines = null, colors = null;
  const surfMat = new THREE.MeshPhongMaterial({ vertexColors: THREE.VertexColors, side: THREE.DoubleSide,
    shininess: 20, specular: 0x222222 });
  const wireMat = new THREE.MeshBasicMaterial({ color: 0x000000, wireframe: true, transparent: true, opacity: 0.25 });
  let wireMesh = null;

  function buildTopology(buf) {
    const dv = new DataView(buf);
    const nVis = dv.getUint32(4, true), nTri = dv.getUint32(8, true), version = dv.getFloat64(16, true);
    const rest = new Float32Array(buf.slice(24, 24 + 12 * nVis));
    const tri = new Uint32Array(buf.slice(24 + 12 * nVis, 24 + 12 * nVis + 12 * nTri));
    const first = !S.topo;
    S.topo = { version, nVis, nTri, rest, tri };
    [surf, restMesh, wireMesh].forEach((m) => { if (m) { scene.remove(m); m.geometry.dispose(); } });
    if (restLines) { scene.remove(restLines); restLines.children.forEach((c) => c.geometry.dispose()); }
    const g = new THREE.BufferGeometry();
    g.setIndex(new THREE.BufferAttribute(tri, 1));
    g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(rest), 3));
    colors = new Float32Array(3 * nVis);
    g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
    g.computeVertexNormals();
    g.computeBoundingSphere();
    surf = new THREE.Mesh(g, surfMat);
    scene.add(surf);
    wireMesh = new THREE.Mesh(g, wireMat);
    wireMesh.visible = $('opt-wire').checked;
    scene.add(wireMesh);
    const rg = new THREE.BufferGeometry();
    rg.setIndex(new THREE.BufferAttribute(tri, 1));
    rg.setAttribute('position', new THREE.BufferAttribute(rest, 3));
    rg.computeVertexNormals();
    rg.computeBoundingSphere();
    restMesh = new THREE.Mesh(rg, new THREE.MeshBasicMaterial({ side: THREE.DoubleSide }));
    restMesh.visible = false; // raycast target for the mouse probe (the surface at rest)
    // Rest outline: the rest surface as a faint ghost plus its feature edges, so a dent shows
    // against where the surface was.
    restLines = new THREE.Group();
    // (pushed back in depth: it shows where the surface moved inward, not where they coincide)
    restLines.add(new THREE.Mesh(rg, new THREE.MeshBasicMaterial({ color: 0xc8d0d8, transparent: true,
      opacity: 0.22, depthWrite: false, side: THREE.DoubleSide, polygonOffset: true,
      polygonOffsetFactor: 2, polygonOffsetUnits: 4 })));
    restLines.add(new THREE.LineSegments(new THREE.EdgesGeometry(rg, 25),
      new THREE.LineBasicMaterial({ color: 0xc0c8d0, transparent: true, opacity: 0.6 })));
    restLines.visible = $('opt-rest').checked;
    scene.add(restLines);
    recolor(null);
    if (first) fitView();
  }

  function fitView() {
    if (!surf) return;
    const bs = surf.geometry.boundingSphere;
    controls.target.copy(bs.center);
    const d = bs.radius / Math.sin(THREE.MathUtils ? THREE.MathUtils.degToRad(camera.fov / 2) : camera.fov * Math.PI / 360);
    const dir = new THREE.Vector3(0.55, 0.65, 0.75).normalize();
    camera.position.copy(bs.center).addScaledVector(dir, d * 1.05);
    camera.near = d / 100; camera.far = d * 10;
    camera.updateProjectionMatrix();
    controls.update();
  }

  // Cool-to-warm: blue 0, grey at half range, red at the range (as hapsim-view's PNGs).
  function colormap(t, out, o) {
    t = Math.max(0, Math.min(1, t));
    const c0 = [0.23, 0.30, 0.75], c1 = [0.87, 0.87, 0.87], c2 = [0.71, 0.02, 0.15];
    let a, b, u;
    if (t < 0.5) { a = c0; b = c1; u = t * 2; } else { a = c1; b = c2; u = (t - 0.5) * 2; }
    out[o] = a[0] + (b[0] - a[0]) * u; out[o + 1] = a[1] + (b[1] - a[1]) * u; out[o + 2] = a[2] + (b[2] - a[2]) * u;
  }

  function niceCeil(x) {
    const e = Math.pow(10, Math.floor(Math.log10(x)));
    const m = x / e;
    return (m <= 1 ? 1 : m <= 2 ? 2 : m <= 5 ? 5 : 10) * e;
  }

  // The scalar shown: displacement magnitude (m), or the server's von Mises stress (Pa) when it
  // sends one and it is chosen. S.unit is what the colour bar prints.
  function recolor(pos, stress) {
    const T = S.topo, rest = T.rest, n = T.nVis;
    let mx = 0, smx = 0;
    const d = new Float32Array(n);
    if (pos) for (let i = 0; i < n; i++) {
      const dx = pos[3 * i] - rest[3 * i], dy = pos[3 * i + 1] - rest[3 * i + 1], dz = pos[3 * i + 2] - rest[3 * i + 2];
      d[i] = Math.sqrt(dx * dx + dy * dy + dz * dz);
      if (d[i] > mx) mx = d[i];
    }
    S.maxDisp = mx;
    const opt = $('opt-field');
    opt.options[1].disabled = !stress;
    const useStress = stress && opt.value === 'stress';
    if (useStress) for (let i = 0; i < n; i++) { d[i] = stress[i]; if (d[i] > smx) smx = d[i]; }
    const unit = useStress ? { name: 'σvM kPa', scale: 1e-3, floor: 100 } : { name: '|u| mm', scale: 1e3, floor: 0.5e-3 };
    if (S.unit && S.unit.name !== unit.name) S.rangeSetAt = 0, S.range = 0;
    S.unit = unit;
    $('range-unit').textContent = useStress ? 'kPa' : 'mm';
    if (useStress) mx = smx;
    S.curMax = mx;
    const fixed = parseFloat($('opt-range').value);
    const now = performance.now();
    if (fixed > 0) S.range = fixed / unit.scale;
    else {
      // Auto: at least 0.5 mm (100 Pa) so a press of 1 mm is plainly red; up at once, down after 3 s.
      const want = niceCeil(Math.max(mx * 1.05, unit.floor));
      if (want > S.range || (want < S.range && now - S.rangeSetAt > 3000)) { S.range = want; S.rangeSetAt = now; }
      if (want >= S.range) S.rangeSetAt = now;
    }
    for (let i = 0; i < n; i++) colormap(d[i] / S.range, colors, 3 * i);
    surf.geometry.attributes.color.needsUpdate = true;
  }

  function applyPositions(buf) {
    if (!S.topo) return;
    const dv = new DataView(buf);
    const nVis = dv.getUint32(4, true), version = dv.getFloat64(8, true);
    if (version !== S.topo.version || nVis !== S.topo.nVis) return; // waits for its topology
    const pos = new Float32Array(buf, 40, 3 * nVis);
    const stress = dv.getUint32(32, true) ? new Float32Array(buf, 40 + 12 * nVis, nVis) : null;
    const attr = surf.geometry.attributes.position;
    attr.array.set(pos);
    attr.needsUpdate = true;
    surf.geometry.computeVertexNormals();
    S.frame = { version, simTime: dv.getFloat64(16, true), simStep: dv.getFloat64(24, true) };
    S.frames++;
    S.lastPos = pos; S.lastStress = stress;
    recolor(pos, stress);
  }

  // ---------------------------------------------------------------- tools
  const toolObjs = {}; // dev -> {sphere, blade, arrow}
  const FORCE_M_PER_N = 0.05; // arrow length per newton (5 cm/N)
  function updateTools() {
    const seen = {};
    for (const t of S.tools) {
      seen[t.dev] = true;
      let o = toolObjs[t.dev];
      if (!o) {
        o = toolObjs[t.dev] = {
          sphere: new THREE.Mesh(new THREE.SphereBufferGeometry(1, 24, 16),
            new THREE.MeshPhongMaterial({ color: 0xe8b04a, transparent: true, opacity: 0.85 })),
          // A blade as a thin rod (WebGL draws lines one pixel wide whatever their width).
          blade: new THREE.Mesh(new THREE.CylinderBufferGeometry(1, 1, 1, 12),
            new THREE.MeshPhongMaterial({ color: 0xf0f0f0 })),
          arrow: new THREE.ArrowHelper(new THREE.Vector3(0, 1, 0), new THREE.Vector3(), 0.01, 0x44e0ff),
        };
        scene.add(o.sphere); scene.add(o.blade); scene.add(o.arrow);
      }
      const isProbe = t.kind === 0;
      o.sphere.visible = isProbe;
      o.blade.visible = !isProbe;
      if (isProbe) {
        o.sphere.position.set(t.p[0], t.p[1], t.p[2]);
        o.sphere.scale.setScalar(Math.max(t.r, 1e-4));
        o.sphere.material.color.setHex(t.contact ? 0xff9d3b : 0xe8b04a);
      } else {
        const a = new THREE.Vector3(t.a[0], t.a[1], t.a[2]), b = new THREE.Vector3(t.b[0], t.b[1], t.b[2]);
        const d = b.clone().sub(a), len = Math.max(d.length(), 1e-6);
        o.blade.position.copy(a).addScaledVector(d, 0.5);
        o.blade.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), d.divideScalar(len));
        o.blade.scale.set(0.0004, len, 0.0004);
        o.blade.material.color.setHex(t.cutting ? 0xff5050 : 0xf0f0f0);
      }
      // Force arrow from the tool's surface (a probe's sphere would hide a short one), its
      // length proportional to |F| (FORCE_M_PER_N), capped at 8 cm.
      const f = new THREE.Vector3(t.f[0], t.f[1], t.f[2]), fn = f.length();
      o.arrow.visible = fn > 1e-4;
      if (o.arrow.visible) {
        const dir = f.clone().divideScalar(fn), len = Math.min(fn * FORCE_M_PER_N, 0.08);
        o.arrow.position.set(t.p[0], t.p[1], t.p[2]).addScaledVector(dir, isProbe ? t.r : 0);
        o.arrow.setDirection(dir);
        o.arrow.setLength(len, Math.min(0.3 * len, 0.008), Math.min(0.15 * len, 0.004));
      }
    }
    for (const k of Object.keys(toolObjs)) {
      if (!seen[k]) { const o = toolObjs[k]; o.sphere.visible = o.blade.visible = o.arrow.visible = false; }
    }
    // Readout: the force each tool applies (N), as the server sends it with the tool state.
    const el = $('readout');
    if (!S.tools.length) { el.textContent = 'no live tool'; return; }
    el.innerHTML = S.tools.map((t) => {
      const fn = Math.hypot(t.f[0], t.f[1], t.f[2]);
      const who = S.mouse.active && S.mouse.dev === t.dev ? ' (mouse)' : '';
      return `<div>device ${t.dev}${who} ${t.kind === 0 ? 'probe' : 'blade'}: <span class="big" data-dev="${t.dev}" data-force="${fn}">${fn.toFixed(3)} N</span>` +
        `<br>(${t.f.map((v) => v.toFixed(3)).join(', ')}) N ${t.contact ? 'contact' : 'free'}</div>`;
    }).join('');
  }

  // ---------------------------------------------------------------- force strip chart
  const CHART_S = 20;
  function pushHistory() {
    const now = performance.now() / 1000;
    const f = {};
    for (const t of S.tools) f[t.dev] = Math.hypot(t.f[0], t.f[1], t.f[2]);
    S.history.push({ t: now, f });
    while (S.history.length && S.history[0].t < now - CHART_S) S.history.shift();
  }
  const DEV_COLORS = ['#44e0ff', '#ffb454', '#a0e070', '#f080c0'];
  function drawChart() {
    const c = $('chart'), g = c.getContext('2d'), W = c.width, H = c.height;
    g.clearRect(0, 0, W, H);
    const now = performance.now() / 1000;
    let fmax = 0.5;
    for (const h of S.history) for (const k in h.f) fmax = Math.max(fmax, h.f[k]);
    fmax = niceCeil(fmax);
    const L = 34, B = 16;
    g.strokeStyle = '#3a414d'; g.fillStyle = '#9aa5b1'; g.font = '10px sans-serif';
    for (let i = 0; i <= 4; i++) {
      const y = (H - B) - (H - B - 14) * i / 4;
      g.beginPath(); g.moveTo(L, y); g.lineTo(W, y); g.stroke();
      g.fillText((fmax * i / 4).toFixed(fmax < 2 ? 2 : 1), 2, y + 3);
    }
    g.fillText('|F| N', L + 4, 10);
    g.fillText(`last ${CHART_S} s`, W - 50, H - 3);
    const devs = new Set();
    for (const h of S.history) for (const k in h.f) devs.add(k);
    for (const d of devs) {
      g.strokeStyle = DEV_COLORS[d % DEV_COLORS.length]; g.lineWidth = 1.5; g.beginPath();
      let pen = false;
      for (const h of S.history) {
        if (!(d in h.f)) { pen = false; continue; }
        const x = L + (W - L) * (1 - (now - h.t) / CHART_S), y = (H - B) - (H - B - 14) * h.f[d] / fmax;
        if (pen) g.lineTo(x, y); else g.moveTo(x, y);
        pen = true;
      }
      g.stroke();
    }
  }

  // ---------------------------------------------------------------- overlay: colour bar, scale, axes
  function drawOverlay() {
    const W = overlay.width, H = overlay.height, dpr = window.devicePixelRatio || 1;
    ctx2d.setTransform(dpr, 0, 0, dpr, 0, 0);
    const w = W / dpr, h = H / dpr;
    ctx2d.clearRect(0, 0, w, h);
    if (!S.topo) return;
    // Colour bar (top right): 0 .. range in mm.
    const bx = w - 70, by = 64, bh = Math.min(220, h * 0.4), bw = 16;
    const grad = ctx2d.createLinearGradient(0, by + bh, 0, by);
    const tmp = [0, 0, 0];
    for (let i = 0; i <= 10; i++) {
      colormap(i / 10, tmp, 0);
      grad.addColorStop(i / 10, `rgb(${tmp.map((v) => Math.round(v * 255)).join(',')})`);
    }
    ctx2d.fillStyle = grad; ctx2d.fillRect(bx, by, bw, bh);
    ctx2d.strokeStyle = '#ccc'; ctx2d.strokeRect(bx, by, bw, bh);
    ctx2d.fillStyle = '#e8edf2'; ctx2d.font = '12px sans-serif';
    const unit = S.unit || { name: '|u| mm', scale: 1e3 };
    const rmm = S.range * unit.scale;
    for (let i = 0; i <= 4; i++) {
      const y = by + bh - bh * i / 4;
      ctx2d.fillRect(bx + bw, y - 0.5, 4, 1);
      ctx2d.fillText((rmm * i / 4).toFixed(rmm < 2 ? 2 : 1), bx + bw + 6, y + 4);
    }
    ctx2d.fillText(unit.name, bx - 8, by - 8);
    ctx2d.fillText(`max ${(S.maxDisp * 1e3).toFixed(2)} mm`, bx - 40, by + bh + 18);
    ctx2d.fillStyle = '#44e0ff';
    ctx2d.fillText('force arrow 5 cm/N', bx - 64, by + bh + 36);
    // Scale bar (bottom left, above the toolbar): a nice length at the orbit target's depth.
    const dist = camera.position.distanceTo(controls.target);
    const pxPerM = h / (2 * dist * Math.tan(camera.fov * Math.PI / 360));
    const len = niceCeil(100 / pxPerM * 0.5);
    const lpx = len * pxPerM, sx = 20, sy = h - 50;
    ctx2d.fillStyle = '#e8edf2';
    ctx2d.fillRect(sx, sy, lpx, 3); ctx2d.fillRect(sx, sy - 5, 2, 13); ctx2d.fillRect(sx + lpx - 2, sy - 5, 2, 13);
    ctx2d.fillText(len >= 0.01 ? `${(len * 100).toFixed(0)} cm` : `${(len * 1000).toFixed(0)} mm`, sx + lpx + 6, sy + 5);
    // Axes triad (bottom right of the view): scene axes as the camera sees them.
    const ox = w - 60, oy = h - 70, L = 36;
    const m = camera.matrixWorldInverse.elements;
    const axes = [['x', '#ff5a5a', 0], ['y', '#5adf5a', 1], ['z', '#5aa0ff', 2]];
    for (const [name, col, k] of axes) {
      const vx = m[k * 4 + 0], vy = m[k * 4 + 1];
      ctx2d.strokeStyle = col; ctx2d.fillStyle = col; ctx2d.lineWidth = 2.5;
      ctx2d.beginPath(); ctx2d.moveTo(ox, oy); ctx2d.lineTo(ox + vx * L, oy - vy * L); ctx2d.stroke();
      ctx2d.font = 'bold 12px sans-serif';
      ctx2d.fillText(name, ox + vx * (L + 8) - 4, oy - vy * (L + 8) + 4);
    }
    ctx2d.lineWidth = 1;
  }

  // ---------------------------------------------------------------- status panel
  function fmt(v, d) { return v === null || v === undefined ? '-' : Number(v).toFixed(d); }
  function showStatus(st) {
    S.status = st;
    const loop = (n) => st.loops.find((l) => l.name === n);
    const rt = loop('rt');
    const rows = [
      ['state', `<span class="state-${st.state}">${st.state}</span>`],
      ['scene', st.scene.split('/').pop()],
      ['uptime', `${fmt(st.uptime_s, 1)} s`],
      ['rt rate', rt ? `${fmt(rt.rate_hz, 1)} Hz` : '-'],
      ['rt period p99', rt ? `${fmt(rt.p99_us, 0)} us` : '-'],
      ['rt overruns', rt ? `${rt.overruns}` : '-'],
    ];
    for (const s of st.steps) rows.push([s.name, `p50 ${fmt(s.p50_us, 0)} / p99 ${fmt(s.p99_us, 0)} us`]);
    rows.push(['topology', `v${st.topology_version}`]);
    for (const d of st.devices) {
      const mine = S.mouse.active && S.mouse.dev === d.id ? ' mouse' : '';
      rows.push([`device ${d.id}`, `${d.live ? 'live' : 'idle'}${mine}, ${fmt(d.force_n, 3)} N`]);
    }
    rows.push(['mesh lost/bad', `${st.mesh_lost} / ${st.malformed}`]);
    $('status').tBodies[0].innerHTML = rows.map(([k, v]) => `<tr><td>${k}</td><td>${v}</td></tr>`).join('');
    $('warnings').textContent = st.warnings;
    $('cap-scene').textContent = `scene ${st.scene.split('/').pop()} (${st.state})`;
    $('btn-estop').disabled = false;
  }

  function logAck(a) {
    a.receivedAt = Date.now();
    S.acks.push(a);
    const div = document.createElement('div');
    div.className = a.ok ? 'ack-ok' : 'ack-bad';
    div.textContent = `${a.cmd}: ${a.status}${a.message ? ' - ' + a.message : ''}`;
    const box = $('acks');
    box.prepend(div);
    while (box.childNodes.length > 30) box.removeChild(box.lastChild);
  }

  // ---------------------------------------------------------------- WebSocket
  let ws = null;
  function send(obj) {
    if (obj.cmd) S.lastCommand = { cmd: obj.cmd, sentAt: Date.now() };
    if (ws && ws.readyState === 1) ws.send(JSON.stringify(obj));
  }
  function connect() {
    ws = new WebSocket(`ws://${location.host}/`, 'hapsim');
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => { $('conn').textContent = 'connected'; $('conn').className = 'ok'; };
    ws.onclose = () => {
      $('conn').textContent = 'disconnected: retrying'; $('conn').className = 'bad';
      setTimeout(connect, 1000);
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data !== 'string') {
        const kind = new DataView(ev.data).getUint32(0, true);
        if (kind === 1) buildTopology(ev.data); else if (kind === 2) applyPositions(ev.data);
        dirty = true;
        return;
      }
      const m = JSON.parse(ev.data);
      if (m.t === 'status') showStatus(m);
      else if (m.t === 'tools') {
        S.tools = m.tools; S.models = m.models;
        S.mouse.sent = m.mouse.sent;
        updateTools(); pushHistory();
        dirty = true;
      } else if (m.t === 'ack') logAck(m);
      else if (m.t === 'hello') S.session = m.session;
      else if (m.t === 'probe') probeReply(m);
    };
  }

  // ---------------------------------------------------------------- mouse probe
  const ray = new THREE.Raycaster();
  const P = { want: false, dragging: false, depth: 2e-3, target: null, timer: null, lastHit: null };
  function probeRadius() {
    const t = S.tools.find((x) => x.dev === S.mouse.dev);
    return t && t.r > 0 ? t.r : 0.005;
  }
  function hitAt(ev) {
    if (!restMesh) return null;
    const r = glCanvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((ev.clientX - r.left) / r.width) * 2 - 1, -((ev.clientY - r.top) / r.height) * 2 + 1);
    ray.setFromCamera(ndc, camera);
    // r111's Raycaster skips invisible objects: ask the hidden rest mesh directly.
    const hits = [];
    restMesh.raycast(ray, hits);
    hits.sort((a, b) => a.distance - b.distance);
    if (!hits.length) return null;
    const h = hits[0], n = h.face.normal.clone();
    if (n.dot(ray.ray.direction) > 0) n.negate(); // the side the camera looks at
    return { p: h.point.clone(), n };
  }
  function placeTool(hit, pressing) {
    if (!hit) return;
    const r = probeRadius();
    const off = pressing ? r - P.depth : r + 0.004; // sphere centre: pressed in, or hovering 4 mm clear
    P.target = hit.p.clone().addScaledVector(hit.n, off);
    P.lastHit = hit;
    send({ probe: 'pose', p: [P.target.x, P.target.y, P.target.z] });
  }
  function probeReply(m) {
    S.mouse.active = !!m.active;
    if (m.active) S.mouse.dev = m.dev;
    $('probe-msg').textContent = m.refused ? `refused: ${m.message}` : (m.active ? `mouse is device ${m.dev}. drag to press, wheel: depth ${(P.depth * 1e3).toFixed(1)} mm. ${m.message}` : '');
    $('btn-probe').classList.toggle('on', S.mouse.active);
    if (!m.active) { P.want = false; controls.enabled = true; }
  }
  $('btn-probe').onclick = () => {
    P.want = !S.mouse.active;
    send({ probe: P.want ? 'start' : 'stop' });
  };
  // Heartbeat: the newest target every 50 ms while probing (hapsim-web stops the device's poses
  // when it hears nothing for 0.5 s, and then the server's watchdog ramps the force down).
  setInterval(() => {
    if (S.mouse.active && P.target) send({ probe: 'pose', p: [P.target.x, P.target.y, P.target.z] });
  }, 50);
  glCanvas.addEventListener('pointerdown', (ev) => {
    if (!S.mouse.active || ev.button !== 0) return;
    const hit = hitAt(ev);
    if (!hit) return;
    P.dragging = true;
    controls.enabled = false;
    glCanvas.setPointerCapture(ev.pointerId);
    placeTool(hit, true);
  }, true);
  glCanvas.addEventListener('pointermove', (ev) => {
    if (!S.mouse.active) return;
    const hit = hitAt(ev);
    if (hit) placeTool(hit, P.dragging);
  });
  glCanvas.addEventListener('pointerup', (ev) => {
    if (!P.dragging) return;
    P.dragging = false;
    controls.enabled = true;
    if (P.lastHit) placeTool(P.lastHit, false);
    try { glCanvas.releasePointerCapture(ev.pointerId); } catch (e) { /* already released */ }
  });
  glCanvas.addEventListener('wheel', (ev) => {
    if (!S.mouse.active || !P.dragging) return;
    ev.preventDefault(); ev.stopImmediatePropagation();
    P.depth = Math.max(0, Math.min(0.02, P.depth + (ev.deltaY < 0 ? 0.5e-3 : -0.5e-3)));
    if (P.lastHit) placeTool(P.lastHit, true);
    $('probe-msg').textContent = `mouse is device ${S.mouse.dev}. depth ${(P.depth * 1e3).toFixed(1)} mm`;
  }, { capture: true, passive: false });

  // ---------------------------------------------------------------- controls
  document.querySelectorAll('button[data-cmd]').forEach((b) => {
    b.onclick = () => send({ cmd: b.dataset.cmd });
  });
  $('set-form').onsubmit = (ev) => {
    ev.preventDefault();
    send({ cmd: 'set', name: $('set-name').value, value: $('set-value').value.trim() });
  };
  $('opt-rest').onchange = () => { if (restLines) restLines.visible = $('opt-rest').checked; dirty = true; };
  $('opt-wire').onchange = () => { if (wireMesh) wireMesh.visible = $('opt-wire').checked; dirty = true; };
  $('btn-fit').onclick = fitView;
  const refresh = () => { if (S.topo && surf) { recolor(S.lastPos || null, S.lastStress || null); dirty = true; } };
  $('opt-field').onchange = refresh;
  // An automatic range comes down 3 s after the organ relaxed, even when no frame arrives.
  setInterval(() => {
    const u = S.unit;
    if (!u || parseFloat($('opt-range').value) > 0 || !S.lastPos) return;
    const want = niceCeil(Math.max((S.curMax || 0) * 1.05, u.floor));
    if (want < S.range && performance.now() - S.rangeSetAt > 3000) refresh();
  }, 1000);
  $('opt-range').onchange = refresh;

  // The pixel (CSS px, page coordinates) of a scene point: for tests and tooltips.
  window.hapsim.project = (p) => {
    const v = new THREE.Vector3(p[0], p[1], p[2]).project(camera);
    const r = glCanvas.getBoundingClientRect();
    return [r.left + (v.x + 1) / 2 * r.width, r.top + (1 - v.y) / 2 * r.height];
  };
  window.hapsim.send = send;

  // ---------------------------------------------------------------- render loop
  function resize() {
    const r = glCanvas.getBoundingClientRect(), dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(r.width)), h = Math.max(1, Math.round(r.height));
    if (glCanvas.width !== Math.round(w * dpr) || glCanvas.height !== Math.round(h * dpr)) {
      dirty = true;
      renderer.setPixelRatio(dpr);
      renderer.setSize(w, h, false);
      overlay.width = Math.round(w * dpr); overlay.height = Math.round(h * dpr);
      camera.aspect = w / h;
      camera.updateProjectionMatrix();
    }
  }
  // Draw only when something changed (new frame, tools, camera, size): a page left open all
  // day costs nothing while the organ rests, and a software-rendered browser stays responsive.
  let dirty = true, lastPanels = 0;
  window.hapsim.redraw = () => { dirty = true; };
  controls.addEventListener('change', () => { dirty = true; });
  function tick(now) {
    resize();
    controls.update();
    if (dirty) {
      dirty = false;
      renderer.render(scene, camera);
      drawOverlay();
      if (S.frame) $('cap-time').textContent = `t = ${S.frame.simTime.toFixed(2)} s  step ${S.frame.simStep}  topology v${S.frame.version}`;
    }
    if (now - lastPanels > 200) { lastPanels = now; drawChart(); }
    requestAnimationFrame(tick);
  }
  connect();
  requestAnimationFrame(tick);
})();
