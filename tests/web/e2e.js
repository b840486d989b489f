// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-web end to end (run by tests/test_web_e2e.sh inside a private network namespace, with
// hapsim-server already serving the liver and hapsim-web on URL). Drives the Debian chromium with
// puppeteer-core. Every check fails the run with a message; screenshots go to OUT.
//   node e2e.js URL OUT STYLUS PROBE_SCRIPT
'use strict';
const fs = require('fs');
const path = require('path');
const { spawn } = require('child_process');
const puppeteer = require('puppeteer-core');

const [url, out, stylusExe, probeScript] = process.argv.slice(2);
const failures = [];
const t0 = Date.now();
function log(msg) { console.log(`[${((Date.now() - t0) / 1000).toFixed(1)} s] ${msg}`); }
function check(ok, what) {
  log(`${ok ? 'ok  ' : 'FAIL'} ${what}`);
  if (!ok) failures.push(what);
  return ok;
}
// A button press through the page's own handler (a DOM click: puppeteer's pointer click waits
// for the software-rendered page to settle, seconds on a loaded machine).
const clickButton = (page, sel) => page.$eval(sel, (b) => b.click());
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function waitFor(page, fn, arg, timeoutMs, what) {
  const end = Date.now() + timeoutMs;
  for (;;) {
    const v = await page.evaluate(fn, arg);
    if (v) return v;
    if (Date.now() > end) throw new Error(`timed out after ${timeoutMs} ms waiting for ${what}`);
    await sleep(100);
  }
}

// Decode a screenshot with the browser's own PNG decoder and measure regions of it (CSS px).
async function analyse(page, png, regions) {
  return page.evaluate(async (b64, regions) => {
    const img = new Image();
    img.src = 'data:image/png;base64,' + b64;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.width; c.height = img.height;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const res = {};
    for (const [name, x, y, w, h] of regions) {
      const d = g.getImageData(Math.round(x), Math.round(y), Math.max(1, Math.round(w)), Math.max(1, Math.round(h))).data;
      let n = 0, organ = 0, red = 0, blue = 0, r = 0, gg = 0, b = 0;
      for (let i = 0; i < d.length; i += 4) {
        const R = d[i], G = d[i + 1], B = d[i + 2];
        n++; r += R; gg += G; b += B;
        // background is (29, 33, 40); organ pixels are lit and colour-mapped
        if (Math.abs(R - 29) + Math.abs(G - 33) + Math.abs(B - 40) > 60) organ++;
        if (R > 120 && R > B + 40) red++;
        if (B > 100 && B > R + 40) blue++;
      }
      res[name] = { n, organ: organ / n, red: red / n, blue: blue / n, mean: [r / n, gg / n, b / n] };
    }
    return res;
  }, png.toString('base64'), regions);
}

function readTrace(file) {
  const lines = fs.readFileSync(file, 'utf8').split('\n');
  const head = lines[0].split(',');
  const col = (n) => head.indexOf(n);
  const rows = [];
  const summary = {};
  for (const l of lines.slice(1)) {
    if (!l) continue;
    if (l[0] === '#') {
      const m = /^#\s*([a-z_0-9]+)=(.*)$/.exec(l);
      if (m) summary[m[1]] = m[2];
      continue;
    }
    const v = l.split(',').map(Number);
    rows.push({ t: v[col('t_s')], seg: v[col('segment')],
      f: Math.hypot(v[col('f_app_x')], v[col('f_app_y')], v[col('f_app_z')]),
      frecv: Math.hypot(v[col('f_recv_x')], v[col('f_recv_y')], v[col('f_recv_z')]) });
  }
  return { rows, summary };
}

function median(a) { const s = [...a].sort((x, y) => x - y); return s.length ? s[Math.floor(s.length / 2)] : NaN; }

async function main() {
  const profile = fs.mkdtempSync(path.join(out, 'chromium-profile-'));
  const browser = await puppeteer.launch({
    executablePath: '/usr/bin/chromium',
    headless: true,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--disable-gpu',
      '--disable-quic', '--no-first-run', '--disable-background-networking', '--disable-component-update',
      '--disable-sync', `--user-data-dir=${profile}`, '--window-size=1280,720'],
    defaultViewport: { width: 1280, height: 720 },
  });
  let stylus = null;
  try {
    const page = await browser.newPage();
    const consoleErrors = [];
    page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
    page.on('pageerror', (e) => consoleErrors.push(String(e)));
    page.on('requestfailed', (r) => consoleErrors.push(`request failed: ${r.url()}`));
    page.on('response', (r) => { if (r.status() >= 400) consoleErrors.push(`HTTP ${r.status()} ${r.url()}`); });
    await page.goto(url, { waitUntil: 'load', timeout: 15000 });
    await waitFor(page, () => window.hapsim && window.hapsim.S.topo && window.hapsim.S.frames > 0 && window.hapsim.S.status,
      null, 20000, 'topology, positions and status in the page');
    const info = await page.evaluate(() => ({ nVis: hapsim.S.topo.nVis, nTri: hapsim.S.topo.nTri, state: hapsim.S.status.state }));
    log(`page has the mesh: ${info.nVis} nodes, ${info.nTri} triangles, server ${info.state}`);
    await sleep(500);

    // 1. Idle picture: organ drawn, colour bar present.
    const probeTop = [-0.0602, 0.0633, -0.0146]; // node 399, where the stylus presses
    const shot1 = await page.screenshot({ path: path.join(out, 'web-01-idle.png') });
    const px = await page.evaluate((p) => hapsim.project(p), probeTop);
    const viewW = await page.evaluate(() => document.getElementById('gl').getBoundingClientRect().width);
    const R = 14;
    const regions = [['view', 0, 40, viewW, 600], ['bar_top', viewW - 68, 68, 12, 20], ['bar_bottom', viewW - 68, 64 + 220 - 24, 12, 20],
      ['probe', px[0] - R, px[1] - R + 4, 2 * R, R]];
    const a1 = await analyse(page, shot1, regions);
    check(a1.view.organ > 0.05, `organ pixels present in the idle screenshot (${(100 * a1.view.organ).toFixed(1)} % of the view differ from the background)`);
    check(a1.bar_top.red > 0.8 && a1.bar_bottom.blue > 0.8, `colour bar present: red at the top (${(100 * a1.bar_top.red).toFixed(0)} %), blue at the bottom (${(100 * a1.bar_bottom.blue).toFixed(0)} %)`);
    check(a1.probe.organ > 0.5, `the press point (${px.map((v) => v.toFixed(0)).join(', ')}) is on the organ in the picture`);

    // 2. A scripted stylus press: colours change at the probe, the readout matches the trace.
    const trace = path.join(out, 'web-stylus-trace.csv');
    const stylusLog = fs.openSync(path.join(out, 'web-stylus.log'), 'w');
    const tStylus = Date.now();
    stylus = spawn(stylusExe, ['--script', probeScript, '--trace', trace, '--realtime'], { stdio: ['ignore', stylusLog, stylusLog] });
    const stylusDone = new Promise((res) => stylus.on('exit', (code) => res(code)));
    const samples = []; // [t since stylus start (s), |F| readout of device 0]
    let onset = -1;
    const readForce = () => page.evaluate(() => {
      const t = hapsim.S.tools.find((x) => x.dev === 0);
      return t ? Math.hypot(t.f[0], t.f[1], t.f[2]) : -1;
    });
    for (;;) { // until 7.4 s after the force first passed 0.05 N: past the steady hold, still pressed
      const tb = Date.now();
      const f = await readForce();
      const t = ((tb + Date.now()) / 2 - tStylus) / 1000; // the middle of the round trip
      samples.push([t, f]);
      if (onset < 0 && f > 0.05) onset = t;
      if (onset >= 0 && t > onset + 7.4) break;
      if (t > 30) {
        const ts = await page.evaluate(() => [hapsim.S.status.tool_states, JSON.stringify(hapsim.S.tools)]);
        throw new Error(`the stylus press never reached 0.05 N on the page readout (max ${Math.max(...samples.map((s) => s[1])).toFixed(3)} N; tool states received ${ts[0]}, tools ${ts[1]})`);
      }
      await sleep(50);
    }
    const shot2 = await page.screenshot({ path: path.join(out, 'web-02-stylus-press.png') });
    const a2 = await analyse(page, shot2, regions);
    const dmax = await page.evaluate(() => hapsim.S.maxDisp);
    check(dmax > 2e-3, `the press deforms the mesh on the page (max displacement ${(dmax * 1e3).toFixed(2)} mm)`);
    const dmean = a2.probe.mean.map((v, i) => Math.abs(v - a1.probe.mean[i])).reduce((x, y) => x + y);
    check(dmean > 40 && a2.probe.red > a1.probe.red + 0.2, `colours change at the probe (mean RGB moved by ${dmean.toFixed(0)}, red share ${(100 * a1.probe.red).toFixed(0)} % -> ${(100 * a2.probe.red).toFixed(0)} %)`);
    // The stylus drives the scene's only device, still pressing: the mouse is refused, politely
    // (asked before the E-STOP, whose answer took seconds on a loaded machine).
    await clickButton(page, '#btn-probe');
    const busy = await waitFor(page, () => (document.getElementById('probe-msg').textContent.includes('refused') || hapsim.S.mouse.active) &&
      `${document.getElementById('probe-msg').textContent} [${JSON.stringify(hapsim.S.status.devices)}]`, null, 8000, 'an answer to the mouse probe while the stylus is live');
    const wrongly = await page.evaluate(() => hapsim.S.mouse.active);
    if (wrongly) await clickButton(page, '#btn-probe'); // give it back
    check(/no free device/.test(busy) && !wrongly, `mouse refused while the stylus holds device 0: "${busy}"`);
    // 3. E-STOP from the page while the stylus holds its press.
    const tEstop = (Date.now() - tStylus) / 1000;
    if (tEstop > onset + 26) throw new Error(`too slow: E-STOP would come ${(tEstop - onset).toFixed(1)} s after the onset, after the held press`);
    const clickAt = Date.now();
    await clickButton(page, '#btn-estop');
    const clickDone = Date.now();
    await waitFor(page, () => hapsim.S.status && hapsim.S.status.state === 'estop', null, 3000, 'server state estop');
    const ack = await waitFor(page, () => hapsim.S.acks.find((a) => a.cmd === 'estop' && a.ok), null, 3000, 'the estop ack');
    log(`E-STOP clicked ${tEstop.toFixed(2)} s after the stylus started (force onset on the page at ${onset.toFixed(2)} s); ack after ${ack.attempts} attempt(s), ${ack.rtt_ms} ms, answered ${((Date.now() - tStylus) / 1000 - tEstop).toFixed(2)} s after the click`);
    const lc = await page.evaluate(() => hapsim.S.lastCommand);
    log(`click took ${clickDone - clickAt} ms; page sent ${lc.cmd} ${lc.sentAt - clickAt} ms after the click started, ack received ${ack.receivedAt - lc.sentAt} ms after sending`);
    await sleep(600);
    const fAfter = await readForce();
    check(fAfter >= 0 && fAfter < 1e-3, `page readout after E-STOP: ${fAfter.toFixed(4)} N`);
    await page.screenshot({ path: path.join(out, 'web-03-estop.png') });
    const code = await Promise.race([stylusDone, sleep(45000).then(() => "timeout")]); // the script runs ~36 s
    stylus = null;
    check(code === 0, `hapsim-stylus exit status ${code}`);
    const tr = readTrace(trace);
    // The longest hold (6 s, its second half is the stylus's steady force) and the holds after it.
    const steadySeg = Number(tr.summary.steady_segment);
    const steadyN = Number(tr.summary.steady_force_norm_n);
    // The stylus feels zero from the e-stop on: the last nonzero tick must lie inside the hold
    // after the steady one (the press is still held), with a real force before it.
    let last = tr.rows.length - 1;
    while (last >= 0 && tr.rows[last].f < 1e-3) last--;
    const zeroFrom = tr.rows[last + 1];
    const heldBefore = tr.rows.filter((r) => r.seg === steadySeg + 1 && r.t < tr.rows[last].t - 0.2);
    const meanBefore = heldBefore.reduce((s, r) => s + r.f, 0) / Math.max(1, heldBefore.length);
    check(last >= 0 && zeroFrom && zeroFrom.seg > steadySeg && zeroFrom.seg <= steadySeg + 6 && heldBefore.length > 100 && meanBefore > 0.05,
      `stylus force ${meanBefore.toFixed(3)} N in the held press, exactly 0 from t = ${zeroFrom ? zeroFrom.t.toFixed(2) : '?'} s (segment ${zeroFrom ? zeroFrom.seg : '?'}, the held press is ${steadySeg + 1}-${steadySeg + 6}) to the end of the run (E-STOP clicked ${tEstop.toFixed(2)} s after the stylus started)`);
    // Readout vs trace on one clock: the E-STOP the page sent is where the trace's force drops to
    // zero (the server acts on it within milliseconds), which maps page time onto the trace's
    // t_s. Both are compared over the second half of the steady hold (margins 0.2 s): the
    // readout samples' median against the median of the force the stylus received (the
    // server's model force, which the readout shows); the summary's steady force is the applied
    // one (after the device's clamps and timeouts), printed beside it.
    const offset = zeroFrom ? zeroFrom.t - (lc.sentAt - tStylus) / 1000 : NaN;
    const segRows = tr.rows.filter((r) => r.seg === steadySeg);
    const h1 = segRows[segRows.length - 1].t, hm = (segRows[0].t + h1) / 2;
    const lo = hm + 0.2, hi = h1 - 0.2;
    // Each readout sample against what the stylus received over the 0.3 s before it (the
    // readout goes through 30 Hz tool states, the WebSocket and the page): its error is the
    // smallest relative difference there; the median error must be under 1 %.
    const rowsIn = (t0, t1) => segRows.filter((r) => r.t >= t0 && r.t <= t1);
    const errs = [];
    const pageVals = [];
    for (const [t, f] of samples) {
      const tt = t + offset;
      if (!(tt > lo && tt < hi) || f < 0) continue;
      const near = rowsIn(tt - 0.3, tt + 0.05);
      if (!near.length) continue;
      errs.push(Math.min(...near.map((r) => Math.abs(f - r.frecv) / r.frecv)));
      pageVals.push(f);
    }
    const err = median(errs);
    const traceN = median(rowsIn(lo, hi).map((r) => r.frecv));
    check(errs.length >= 8 && err < 0.01, `readout vs stylus trace over t_s ${lo.toFixed(2)} .. ${hi.toFixed(2)} s (second half of the steady hold; page clock + ${offset.toFixed(2)} s from the E-STOP): median error ${(100 * err).toFixed(2)} % over ${errs.length} samples (< 1 %); readout median ${median(pageVals).toFixed(4)} N, received ${traceN.toFixed(4)} N, applied steady ${steadyN.toFixed(4)} N`);

    // 4. Release, then the mouse as a device.
    await clickButton(page, 'button[data-cmd="estop-release"]');
    await waitFor(page, () => hapsim.S.status && hapsim.S.status.state === 'running', null, 5000, 'state running after release');
    await waitFor(page, () => hapsim.S.status.devices.every((d) => !d.live), null, 5000, 'device 0 idle after the stylus');
    await clickButton(page, '#btn-probe');
    await waitFor(page, () => hapsim.S.mouse.active, null, 3000, 'the mouse probe accepted');
    const p2 = await page.evaluate((p) => hapsim.project(p), probeTop);
    await page.mouse.move(p2[0], p2[1]);
    await sleep(300);
    await page.mouse.down();
    for (let i = 0; i < 10; i++) { await page.mouse.move(p2[0] + i, p2[1]); await sleep(30); }
    for (let i = 0; i < 8; i++) { await page.mouse.wheel({ deltaY: -100 }); await sleep(30); } // 4 mm deeper
    let st;
    try {
      st = await waitFor(page, () => {
        const d = hapsim.S.status.devices.find((x) => x.id === hapsim.S.mouse.dev);
        return d && d.live && d.force_n > 0.05 ? d : null;
      }, null, 5000, 'the server reporting the mouse device live with a force');
    } catch (e) {
      log(`state: ${await page.evaluate(() => JSON.stringify({ mouse: hapsim.S.mouse, dev: hapsim.S.status.devices,
        rejects: hapsim.S.status.rejects, tools: hapsim.S.tools, msg: document.getElementById('probe-msg').textContent }))}`);
      await page.screenshot({ path: path.join(out, 'web-04-mouse-press.png') });
      throw e;
    }
    check(st.live === 1 && st.force_n > 0.05, `server status: mouse device ${st.id} live, ${st.force_n.toFixed(3)} N, ${st.received} poses`);
    await sleep(700);
    const fm = await readForce();
    check(fm > 0.05, `page readout while the mouse presses: ${fm.toFixed(3)} N`);
    await page.screenshot({ path: path.join(out, 'web-04-mouse-press.png') });
    await page.mouse.up();
    // 5. A second browser asking for the mouse is refused politely while this one holds it.
    const page2 = await browser.newPage();
    page2.on('pageerror', (e) => consoleErrors.push(String(e)));
    await page2.goto(url, { waitUntil: 'load', timeout: 15000 });
    await waitFor(page2, () => window.hapsim && hapsim.S.status && hapsim.S.topo, null, 10000, 'second browser connected');
    await clickButton(page2, '#btn-probe');
    const msg = await waitFor(page2, () => document.getElementById('probe-msg').textContent.includes('refused') &&
      document.getElementById('probe-msg').textContent, null, 8000, 'a refusal in the second browser');
    check(/another browser/.test(msg), `second browser refused: "${msg}"`);
    await page2.close();
    await clickButton(page, '#btn-probe');
    await waitFor(page, () => !hapsim.S.mouse.active, null, 3000, 'the mouse probe stopped');
    check(consoleErrors.length === 0, `no console errors (${consoleErrors.length}${consoleErrors.length ? ': ' + consoleErrors.slice(0, 5).join(' | ') : ''})`);
  } finally {
    if (stylus) stylus.kill('SIGINT');
    await browser.close();
    fs.rmSync(profile, { recursive: true, force: true });
  }
}

main().then(() => {
  if (failures.length) { console.log(`web e2e: ${failures.length} check(s) failed`); process.exit(1); }
  console.log('web e2e: all checks passed'); process.exit(0);
}, (e) => { console.log(`web e2e: FAIL ${e.message}`); process.exit(1); });
