// Browser tests of the retex dashboard (issue 16, part 3): Debian's Chromium driven by
// playwright-core against a real `retex serve` (the release binary) on a free port with a
// temporary data directory.
//
//   npm install --prefix tests/browser --no-package-lock playwright-core
//   node tests/browser/run.mjs            # RETEX_BIN, CHROMIUM override the paths
//
// RETEX_DASHBOARD_STATIC=src/service/http/dashboard/static serves the page's index.html, app.js
// and app.css from that folder instead of the binary (to edit the page without rebuilding).
//
// Checks: a `project` job submitted through the form (files given to the drop zones' inputs)
// reaches 100 % on the progress bar, its preview image loads and the 3D view draws a non-blank
// canvas; a slow meshmatch job is canceled from its page; an out-of-range parameter is refused
// next to its field by the page, and a malformed one by the server (problem+json shown next to
// the field it names); with tokens configured, the page asks for one, and the token works.
// Also: files dropped onto the drop zones (dragenter/dragover/drop with a DataTransfer built in
// the page) are what the job is submitted with; the constraints' Copy button puts them on the
// clipboard; the job list is newest first and follows a running job from its event stream
// (GET /v1/events) without a single polling request.
// Screenshots go to target/browser/ and each is checked for being non-blank. Exits non-zero on
// any failure and prints one summary line.

import { spawn } from 'node:child_process';
import fs from 'node:fs';
import net from 'node:net';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { chromium } from 'playwright-core';

const ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const BIN = process.env.RETEX_BIN || path.join(ROOT, 'target/release/retex');
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const SHOTS = path.join(ROOT, 'target/browser');
const SOURCE = path.join(ROOT, 'tests/data/src_spot_keenan/spot_textured_derived.glb');
const TARGET = path.join(ROOT, 'tests/data/tgt_spot_remeshed_odedstein/spot_derived.glb');
const TOKEN = 'browser-test-secret';

const results = [];
const started = Date.now();

function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.once('error', reject);
    s.listen(0, '127.0.0.1', () => { const { port } = s.address(); s.close(() => resolve(port)); });
  });
}

async function startServer(env) {
  const port = await freePort();
  const data = fs.mkdtempSync(path.join(os.tmpdir(), 'retex-browser-'));
  const child = spawn(BIN, ['serve'], {
    env: { ...process.env, RETEX_ADDR: `127.0.0.1:${port}`, RETEX_DATA_DIR: data, RETEX_WORKERS: '1', ...env },
    stdio: ['ignore', 'ignore', 'pipe'],
  });
  let log = '';
  child.stderr.on('data', (d) => { log += d; });
  const base = `http://127.0.0.1:${port}`;
  for (let i = 0; i < 100; i++) {
    try { if ((await fetch(`${base}/healthz`)).ok) return { base, child, data, log: () => log }; } catch {}
    if (child.exitCode !== null) break;
    await new Promise((r) => setTimeout(r, 100));
  }
  child.kill('SIGKILL');
  throw new Error(`retex serve did not start: ${log.slice(-2000)}`);
}

async function stopServer(s) {
  s.child.kill('SIGTERM');
  await new Promise((r) => { if (s.child.exitCode !== null) r(); else s.child.once('exit', r); setTimeout(r, 8000); });
  fs.rmSync(s.data, { recursive: true, force: true });
}

// Pixel statistics of a PNG, decoded by the browser itself: (luminance variance, share of pixels
// away from the most common colour).
async function pngStats(page, png) {
  return page.evaluate(async (b64) => {
    const img = new Image();
    img.src = `data:image/png;base64,${b64}`;
    await img.decode();
    const c = document.createElement('canvas');
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext('2d');
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    let s = 0, s2 = 0; const counts = new Map();
    const n = d.length / 4;
    for (let i = 0; i < d.length; i += 4) {
      const l = 0.299 * d[i] + 0.587 * d[i + 1] + 0.114 * d[i + 2];
      s += l; s2 += l * l;
      const key = (d[i] >> 3) << 10 | (d[i + 1] >> 3) << 5 | (d[i + 2] >> 3);
      counts.set(key, (counts.get(key) || 0) + 1);
    }
    const mode = Math.max(...counts.values());
    return { variance: s2 / n - (s / n) ** 2, varied: 1 - mode / n, width: c.width, height: c.height };
  }, png.toString('base64'));
}

async function shot(page, name, target) {
  fs.mkdirSync(SHOTS, { recursive: true });
  const file = path.join(SHOTS, `${name}.png`);
  const png = await (target || page).screenshot({ path: file });
  const st = await pngStats(page, png);
  if (!(st.variance > 20 && st.varied > 0.02)) {
    throw new Error(`screenshot ${name} looks blank: ${JSON.stringify(st)}`);
  }
  return st;
}

async function step(name, fn) {
  const t0 = Date.now();
  try {
    const detail = await fn();
    results.push({ name, ok: true });
    console.log(`ok   ${name} (${((Date.now() - t0) / 1000).toFixed(1)} s)${detail ? `: ${detail}` : ''}`);
  } catch (e) {
    results.push({ name, ok: false });
    console.log(`FAIL ${name}: ${e.stack || e}`);
  }
}

async function fillForm(page, method) {
  await page.goto(`${page.base}/#/submit`);
  await page.waitForSelector('#method option', { state: 'attached' });
  await page.selectOption('#method', method);
  await page.setInputFiles('[data-part-input=source]', SOURCE);
  await page.setInputFiles('[data-part-input=target]', TARGET);
}

const param = (name) => `[data-field="constraints.params.${name}"]`;
const output = (name) => `[data-field="constraints.output.${name}"]`;

async function openJob(page) {
  await page.waitForFunction(() => /^#\/jobs\/[0-9a-f-]{36}$/.test(location.hash), null, { timeout: 30000 });
  return page.url().split('/').pop();
}

async function overrideStatic(context) {
  const dir = process.env.RETEX_DASHBOARD_STATIC;
  if (!dir) return;
  const types = { html: 'text/html', js: 'text/javascript', css: 'text/css' };
  await context.route(/\/(dashboard\/(app\.js|app\.css))?$/, (r) => {
    const name = new URL(r.request().url()).pathname.replace('/dashboard/', '') || 'index.html';
    const file = name === '/' ? 'index.html' : name;
    r.fulfill({ path: path.resolve(ROOT, dir, file), contentType: types[file.split('.').pop()] });
  });
}

async function main() {
  const browser = await chromium.launch({
    executablePath: CHROMIUM,
    headless: true,
    args: ['--no-sandbox', '--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
  });
  const server = await startServer({});
  const context = await browser.newContext({ viewport: { width: 1280, height: 900 } });
  await overrideStatic(context);
  // The test's model files, for a submission made by a script inside the page.
  await context.route(/\/__(source|target)$/, (r) => r.fulfill({ path: r.request().url().endsWith('source') ? SOURCE : TARGET, contentType: 'model/gltf-binary' }));
  const page = await context.newPage();
  page.base = server.base;
  const pageErrors = [];
  page.on('pageerror', (e) => pageErrors.push(String(e)));
  page.on('dialog', (d) => d.accept());

  await step('project job through the form: progress 100 %, preview, 3D view', async () => {
    await fillForm(page, 'project');
    await page.fill(`${output('texture_size')} input`, '512');
    await page.click('#submit-button');
    const id = await openJob(page);
    await page.waitForFunction(() => document.querySelector('#job-status')?.textContent === 'succeeded', null, { timeout: 120000 });
    const bar = await page.$eval('#job-bar', (b) => ({ width: b.style.width, label: document.querySelector('#job-pct').textContent }));
    if (bar.width !== '100%' || bar.label !== '100%') throw new Error(`progress bar at ${JSON.stringify(bar)}`);
    await page.waitForFunction(() => { const i = document.querySelector('#preview-result'); return i && !i.hidden && i.complete && i.naturalWidth > 0; }, null, { timeout: 30000 });
    const dims = await page.$eval('#preview-result', (i) => [i.naturalWidth, i.naturalHeight]);
    if (dims[0] !== 1024 || dims[1] !== 256) throw new Error(`preview is ${dims}`);
    await page.waitForFunction(() => document.querySelector('#viewer')?.loaded === true, null, { timeout: 60000 });
    // Read the rendered image back until a frame has been drawn (SwiftShader under load can take
    // a few seconds for the first one).
    let st;
    for (let i = 0; i < 60; i++) {
      const view = await page.evaluate(() => {
        const url = document.querySelector('#viewer').toDataURL('image/png');
        return url.slice(url.indexOf(',') + 1);
      });
      st = await pngStats(page, Buffer.from(view, 'base64'));
      if (st.variance > 20 && st.varied > 0.05) break;
      await page.waitForTimeout(500);
    }
    if (!(st.variance > 20 && st.varied > 0.05)) throw new Error(`3D view looks blank: ${JSON.stringify(st)}`);
    const viewerShot = await shot(page, 'viewer', page.locator('#viewer'));
    await shot(page, 'job-page');
    const files = await page.$$eval('[data-download]', (bs) => bs.map((b) => b.dataset.download));
    for (const want of ['preview.png', 'report.json']) if (!files.includes(want)) throw new Error(`no download ${want} in ${files}`);
    const constraints = JSON.parse(await page.textContent('#job-constraints'));
    if (constraints.method !== 'project' || constraints.output?.texture_size !== 512) throw new Error(`constraints ${JSON.stringify(constraints)}`);
    const timings = await page.$$eval('#job-timings tr', (rs) => rs.map((r) => [r.cells[0].textContent, parseFloat(r.cells[1].textContent)]));
    const previewMs = timings.filter(([k]) => k.startsWith('preview')).reduce((a, [, v]) => a + v, 0);
    const totalMs = timings.reduce((a, [, v]) => a + v, 0);
    return `job ${id.slice(0, 8)}, previews ${previewMs.toFixed(0)} of ${totalMs.toFixed(0)} ms, canvas variance ${st.variance.toFixed(0)}, ${(st.varied * 100).toFixed(0)} % off-background (screenshot ${viewerShot.variance.toFixed(0)})`;
  });

  await step('drag and drop onto the drop zones, copy the constraints', async () => {
    await page.goto(`${server.base}/#/submit`);
    await page.waitForSelector('#method option', { state: 'attached' });
    await page.selectOption('#method', 'project');
    for (const [part, file] of [['source', SOURCE], ['target', TARGET]]) {
      const zone = `[data-part=${part}]`;
      const over = await page.evaluate(async ({ zone, name, b64 }) => {
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const dt = new DataTransfer();
        dt.items.add(new File([bytes], name, { type: 'model/gltf-binary' }));
        const z = document.querySelector(zone);
        const fire = (type) => z.dispatchEvent(new DragEvent(type, { bubbles: true, cancelable: true, dataTransfer: dt }));
        fire('dragenter');
        const refused = !fire('dragover'); // preventDefault: the zone accepts the drop
        const highlighted = z.classList.contains('over');
        fire('drop');
        return { refused, highlighted, after: z.classList.contains('over') };
      }, { zone, name: path.basename(file), b64: fs.readFileSync(file).toString('base64') });
      if (!over.refused || !over.highlighted || over.after) throw new Error(`${part} zone drag state ${JSON.stringify(over)}`);
      const shown = await page.textContent(`${zone} .files`);
      const kb = (fs.statSync(file).size / 1024).toFixed(1);
      if (!shown.includes(path.basename(file)) || !shown.includes(kb)) throw new Error(`${part} zone shows ${shown}`);
    }
    await page.fill(`${output('texture_size')} input`, '64');
    await page.click('#submit-button');
    const id = await openJob(page);
    await page.waitForFunction(() => document.querySelector('#job-status')?.textContent === 'succeeded', null, { timeout: 120000 });
    // The server got both dropped files (project needs both): each has its preview.
    const doc = await page.evaluate(async (u) => (await fetch(u)).json(), `/v1/jobs/${id}`);
    const names = doc.links.artifacts.map((a) => a.name);
    for (const want of ['source_preview.png', 'target_preview.png']) if (!names.includes(want)) throw new Error(`no ${want} in ${names}`);
    // Copy: the clipboard holds exactly the constraints shown.
    await page.waitForFunction(() => document.querySelector('#job-constraints')?.textContent.length > 2);
    await page.context().grantPermissions(['clipboard-read', 'clipboard-write'], { origin: server.base });
    await page.evaluate(() => navigator.clipboard.writeText(''));
    await page.click('#copy-constraints');
    const shownText = await page.textContent('#job-constraints');
    let copied = '';
    for (let i = 0; i < 20 && !copied; i++) {
      copied = await page.evaluate(() => navigator.clipboard.readText());
      if (!copied) await page.waitForTimeout(100);
    }
    if (copied !== shownText) throw new Error(`clipboard holds ${JSON.stringify(copied.slice(0, 80))}`);
    const c = JSON.parse(copied);
    if (c.method !== 'project' || c.output?.texture_size !== 64) throw new Error(`copied ${copied.slice(0, 120)}`);
    return `job ${id.slice(0, 8)}, ${copied.length} characters copied`;
  });

  await step('job list: newest first, live from the event stream (no polling)', async () => {
    const requests = [];
    const onRequest = (r) => requests.push({ t: Date.now(), url: new URL(r.url()).pathname + new URL(r.url()).search });
    page.on('request', onRequest);
    try {
      await page.goto(`${server.base}/#/`);
      await page.waitForSelector('#live:not(:empty)');
      if ((await page.textContent('#live')) !== 'live') throw new Error(`list not live: ${await page.textContent('#live')}`);
      // Record every change of every row, as the page shows it.
      await page.evaluate(() => {
        window.rowLog = [];
        new MutationObserver(() => {
          for (const tr of document.querySelectorAll('#job-rows tr')) {
            const pct = tr.querySelector('[role=progressbar]')?.getAttribute('aria-valuenow');
            const last = window.rowLog.findLast((x) => x.id === tr.dataset.id);
            if (!last || last.status !== tr.dataset.status || last.pct !== pct) window.rowLog.push({ t: Date.now(), id: tr.dataset.id, status: tr.dataset.status, pct });
          }
        }).observe(document.querySelector('#job-rows'), { childList: true, subtree: true, attributes: true });
      });
      // A job submitted by a script (not the page): the page learns of it from the stream. It
      // must run long enough for several progress samples (every 250 ms): a 1024² `project`
      // job takes 0.27 s on this machine and once finished before the row moved twice, while
      // MeshMatch at 16,384 samples takes about 2.8 s here and reports progress per EM step.
      const id = await page.evaluate(async () => {
        const fd = new FormData();
        for (const [part, url] of [['source', '/__source'], ['target', '/__target']]) fd.append(part, new Blob([await (await fetch(url)).arrayBuffer()]), `${part}.glb`);
        fd.append('constraints', new Blob([JSON.stringify({ version: 1, method: 'meshmatch', params: { samples: 16384 } })]), 'c.json');
        const r = await fetch('/v1/jobs', { method: 'POST', body: fd });
        return (await r.json()).id;
      });
      if (!id) throw new Error('submission failed');
      try {
        await page.waitForSelector(`#job-rows tr[data-id="${id}"][data-status=succeeded]`, { timeout: 120000 });
      } catch (e) {
        const state = await page.evaluate(async (u) => ({ job: await (await fetch(u)).json(), log: window.rowLog.slice(-20), live: document.querySelector('#live').textContent, hash: location.hash }), `/v1/jobs/${id}`);
        throw new Error(`${e.message}\n${JSON.stringify({ ...state, job: { status: state.job.status, progress: state.job.progress } })}\nrequests ${JSON.stringify(requests.slice(-20))}`);
      }
      const log = (await page.evaluate(() => window.rowLog)).filter((x) => x.id === id);
      const running = log.filter((x) => x.status === 'processing');
      const pcts = new Set(running.map((x) => x.pct));
      if (running.length < 3 || pcts.size < 3) throw new Error(`the row did not move while running: ${JSON.stringify(log)}`);
      // The page loads the list once when a job it does not list first shows up in the stream
      // (`onJobEvent`: one reload per new job, by design); that load can land just after the
      // row's first update, so the no-polling window starts at its second update.
      const [t0, t1] = [running[1].t, running[running.length - 1].t];
      const polled = requests.filter((r) => r.t >= t0 && r.t <= t1 && r.url.startsWith('/v1/jobs'));
      if (polled.length) throw new Error(`requests while the job ran: ${JSON.stringify(polled)}; rows ${JSON.stringify(log)}`);
      const streams = requests.filter((r) => r.url === '/v1/events').length;
      if (streams !== 1) throw new Error(`${streams} event streams opened`);
      // Newest first: the script's job is on top, and creation times never increase downwards.
      await page.waitForFunction(() => document.querySelectorAll('#job-rows tr').length >= 3);
      const rows = await page.$$eval('#job-rows tr', (rs) => rs.map((r) => [r.dataset.id, r.cells[3].title]));
      if (rows[0][0] !== id) throw new Error(`top row is ${rows[0][0]}, not the newest job ${id}`);
      for (let i = 1; i < rows.length; i++) {
        if (Date.parse(rows[i][1]) > Date.parse(rows[i - 1][1])) throw new Error(`order: ${JSON.stringify(rows)}`);
      }
      return `${running.length} live updates (${[...pcts].join(', ')} %) in ${((t1 - t0) / 1000).toFixed(1)} s, 0 list requests; ${rows.length} rows newest first`;
    } finally {
      page.off('request', onRequest);
    }
  });

  await step('job list: status filter, phone layout', async () => {
    await page.goto(`${server.base}/#/`);
    await page.waitForSelector('#job-rows tr[data-status=succeeded]');
    // The filter shows only failed jobs: none, or only rows with that status (a job of another
    // step may have failed; that step reports its own job, this one checks the filter).
    await page.selectOption('#filter-status', 'failed');
    await page.waitForFunction(() => {
      const rows = [...document.querySelectorAll('#job-rows tr')];
      const empty = !document.querySelector('#jobs-empty').hidden;
      return (empty && rows.length === 0) || (rows.length > 0 && rows.every((r) => r.dataset.status === 'failed'));
    });
    const failedRows = await page.$$eval('#job-rows tr', (rs) => rs.map((r) => r.dataset.id));
    if (failedRows.length) console.log(`note: failed jobs listed by the filter: ${failedRows.join(', ')}`);
    await page.selectOption('#filter-status', '');
    await page.waitForSelector('#job-rows tr');
    await shot(page, 'jobs');
    await page.setViewportSize({ width: 390, height: 844 });
    await shot(page, 'jobs-phone');
    const overflow = await page.evaluate(() => document.documentElement.scrollWidth - window.innerWidth);
    await page.setViewportSize({ width: 1280, height: 900 });
    if (overflow > 2) throw new Error(`phone layout scrolls sideways by ${overflow} px`);
  });

  await step('bad parameters: refused next to their fields', async () => {
    await fillForm(page, 'meshmatch');
    // Out of range: the page refuses before sending.
    await page.fill(`${param('samples')} input`, '10');
    await page.click('#submit-button');
    const local = await page.textContent(`${param('samples')} .error`);
    if (!/at least 256/.test(local)) throw new Error(`samples error: ${local}`);
    await page.fill(`${param('samples')} input`, '');
    // Well-formed JSON the server refuses: its problem+json lands next to the field.
    await page.fill(`${param('hks')} textarea`, '{"eigenpairs": 100, "bogus": 1}');
    await page.click('#submit-button');
    await page.waitForSelector(`${param('hks')}.invalid .error:not([hidden])`, { timeout: 30000 });
    const server = await page.textContent(`${param('hks')} .error`);
    if (!/bogus/.test(server)) throw new Error(`hks error: ${server}`);
    if (!page.url().endsWith('#/submit')) throw new Error(`left the form: ${page.url()}`);
    await shot(page, 'field-error');
    return server.slice(0, 90);
  });

  await step('cancel a slow meshmatch job, then delete it', async () => {
    await fillForm(page, 'meshmatch');
    await page.fill(`${param('samples')} input`, '262144');
    await page.fill(`${param('iterations')} input`, '100');
    await page.click('#submit-button');
    await openJob(page);
    await page.waitForFunction(() => document.querySelector('#job-status')?.textContent === 'processing', null, { timeout: 60000 });
    await page.click('#job-cancel');
    await page.waitForFunction(() => document.querySelector('#job-status')?.textContent === 'canceled', null, { timeout: 20000 });
    await shot(page, 'canceled');
    // Delete (the confirm dialog is accepted): back to the list, and the job is gone.
    const id = page.url().split('/').pop();
    await page.click('#job-delete');
    await page.waitForFunction(() => location.hash === '#/', null, { timeout: 10000 });
    const gone = await page.evaluate(async (u) => (await fetch(u)).status, `/v1/jobs/${id}`);
    if (gone !== 404) throw new Error(`deleted job answers ${gone}`);
  });

  await step('job list: pagination, older and newer pages', async () => {
    // More jobs than one page (PAGE_SIZE 20), submitted by a script and canceled while waiting
    // (a canceled job is listed like any other and costs the worker nothing).
    const made = await page.evaluate(async () => {
      const files = [];
      for (const url of ['/__source', '/__target']) files.push(await (await fetch(url)).arrayBuffer());
      const ids = [];
      for (let i = 0; i < 22; i++) {
        const fd = new FormData();
        fd.append('source', new Blob([files[0]]), 'source.glb');
        fd.append('target', new Blob([files[1]]), 'target.glb');
        fd.append('constraints', new Blob([JSON.stringify({ version: 1, method: 'project', output: { texture_size: 32 } })]), 'c.json');
        const r = await fetch('/v1/jobs', { method: 'POST', body: fd });
        const id = (await r.json()).id;
        await fetch(`/v1/jobs/${id}/cancel`, { method: 'POST' });
        ids.push(id);
      }
      return ids;
    });
    if (made.length !== 22 || made.some((x) => !x)) throw new Error(`submissions: ${JSON.stringify(made)}`);
    await page.goto(`${server.base}/#/`);
    await page.reload();
    await page.waitForSelector('#job-rows tr');
    const rows = () => page.$$eval('#job-rows tr', (trs) => trs.map((tr) => tr.dataset.id));
    const first = await rows();
    if (first.length !== 20) throw new Error(`page 1 shows ${first.length} rows`);
    if (first[0] !== made[21]) throw new Error(`page 1 does not start with the newest job`);
    if (await page.isDisabled('#page-older')) throw new Error('Older is disabled with more jobs than a page');
    if (!(await page.isDisabled('#page-newer'))) throw new Error('Newer is enabled on page 1');
    await page.click('#page-older');
    await page.waitForFunction((id) => !document.querySelector(`#job-rows tr[data-id="${id}"]`), first[0]);
    const second = await rows();
    if (second.length === 0 || second.some((id) => first.includes(id))) throw new Error(`page 2 ${second.length} rows, overlap with page 1`);
    // Every job submitted is on one of the two pages (the earlier steps' jobs fill the rest).
    const missing = made.filter((id) => !first.includes(id) && !second.includes(id));
    if (missing.length) throw new Error(`${missing.length} submitted jobs on neither page`);
    const label = await page.textContent('#page-number');
    if (!/2/.test(label)) throw new Error(`page label ${label}`);
    await page.click('#page-newer');
    await page.waitForFunction((id) => !!document.querySelector(`#job-rows tr[data-id="${id}"]`), first[0]);
    return `page 1: 20 rows from the newest, page 2: ${second.length} rows, no overlap`;
  });

  await context.close();
  await stopServer(server);

  await step('token login when auth is on', async () => {
    const secured = await startServer({ RETEX_TOKENS: TOKEN });
    try {
      const ctx = await browser.newContext({ viewport: { width: 1280, height: 900 } });
      await overrideStatic(ctx);
      const p = await ctx.newPage();
      const requests = [];
      p.on('request', (r) => requests.push(r.url()));
      await p.goto(`${secured.base}/`);
      await p.waitForSelector('#login[open]', { timeout: 10000 });
      await p.fill('#login-token', 'wrong-token');
      await p.click('#login-submit');
      await p.waitForSelector('#login[open] #login-error:not([hidden])', { timeout: 10000 });
      await p.fill('#login-token', TOKEN);
      await p.click('#login-submit');
      await p.waitForSelector('#live:not(:empty)', { timeout: 10000 });
      if (await p.$('#login[open]')) throw new Error('the login dialog stayed open');
      const stored = await p.evaluate(() => sessionStorage.getItem('retex.token'));
      if (stored !== TOKEN) throw new Error('token not in sessionStorage');
      await p.goto(`${secured.base}/#/submit`);
      await p.waitForSelector('#method option', { state: 'attached' });
      if (requests.some((u) => u.includes(TOKEN))) throw new Error('the token appeared in a URL');
      await shot(p, 'login-submit-form');
      await ctx.close();
    } finally {
      await stopServer(secured);
    }
  });

  await browser.close();
  if (pageErrors.length) {
    results.push({ name: 'no page errors', ok: false });
    console.log(`FAIL page errors: ${pageErrors.join('\n')}`);
  }
}

try {
  await main();
} catch (e) {
  results.push({ name: 'setup', ok: false });
  console.log(`FAIL setup: ${e.stack || e}`);
}
const failed = results.filter((r) => !r.ok).length;
console.log(`browser: ${results.length - failed} passed, ${failed} failed in ${((Date.now() - started) / 1000).toFixed(0)} s (screenshots in target/browser/)`);
process.exit(failed ? 1 : 0);
