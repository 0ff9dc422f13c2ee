// retex dashboard: plain ES module, no build step. Views by URL hash: #/ (jobs), #/submit,
// #/jobs/<id>. Every API call carries the bearer token from sessionStorage (never a URL);
// downloads, previews and the 3D model are fetched with it and shown through object URLs.

const TOKEN_KEY = 'retex.token';
const PAGE_SIZE = 20;
const LIST_POLL_MS = 1500; // only while the list's event stream is down
const STREAM_RETRY_MS = 10000;
const $ = (id) => document.getElementById(id);
const el = (tag, attrs = {}, ...kids) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v;
    else if (k === 'text') e.textContent = v;
    else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else if (v !== undefined && v !== null && v !== false) e.setAttribute(k, v === true ? '' : v);
  }
  for (const k of kids) if (k !== null && k !== undefined) e.append(k);
  return e;
};

// ---------- API ----------
class ApiError extends Error {
  constructor(status, problem) {
    super(problem?.detail || problem?.title || `HTTP ${status}`);
    this.status = status;
    this.problem = problem || {};
  }
}

const token = () => sessionStorage.getItem(TOKEN_KEY) || '';
let loginWaiters = [];

async function api(path, opts = {}) {
  const headers = new Headers(opts.headers || {});
  if (token()) headers.set('Authorization', `Bearer ${token()}`);
  const resp = await fetch(path, { ...opts, headers });
  if (resp.status === 401) {
    showLogin(token() ? 'The token was refused.' : '');
    throw new ApiError(401, await problemOf(resp));
  }
  if (!resp.ok && resp.status !== 304) throw new ApiError(resp.status, await problemOf(resp));
  return resp;
}

async function problemOf(resp) {
  try { return await resp.json(); } catch { return { detail: `HTTP ${resp.status}` }; }
}

const apiJson = async (path, opts) => (await api(path, opts)).json();

// ---------- token ----------
function showLogin(message) {
  const d = $('login');
  $('login-error').hidden = !message;
  $('login-error').textContent = message || '';
  if (!d.open) d.showModal();
}

function initLogin() {
  $('token-button').addEventListener('click', () => showLogin(''));
  $('login-form').addEventListener('submit', () => {
    const t = $('login-token').value.trim();
    if (t) sessionStorage.setItem(TOKEN_KEY, t);
    $('login-token').value = '';
    route();
  });
  $('login-forget').addEventListener('click', () => {
    sessionStorage.removeItem(TOKEN_KEY);
    $('login').close();
  });
}

function banner(message) {
  $('banner').hidden = !message;
  $('banner').textContent = message || '';
}

// ---------- formatting ----------
const pct = (f) => `${Math.round(Math.max(0, Math.min(1, f || 0)) * 100)}%`;
function span(seconds) {
  if (!isFinite(seconds) || seconds < 0) return '';
  if (seconds < 60) return `${seconds.toFixed(seconds < 10 ? 1 : 0)} s`;
  if (seconds < 3600) return `${Math.floor(seconds / 60)} min ${Math.round(seconds % 60)} s`;
  if (seconds < 86400) return `${Math.floor(seconds / 3600)} h ${Math.round((seconds % 3600) / 60)} min`;
  return `${Math.floor(seconds / 86400)} d`;
}
const secondsSince = (t, now = Date.now()) => (now - Date.parse(t)) / 1000;
function duration(job) {
  if (!job.started_at) return '';
  const end = job.finished_at ? Date.parse(job.finished_at) : Date.now();
  return span((end - Date.parse(job.started_at)) / 1000);
}
const bytes = (n) => n < 1024 ? `${n} B` : n < 1 << 20 ? `${(n / 1024).toFixed(1)} KB` : `${(n / 1048576).toFixed(1)} MB`;
const terminal = (s) => ['succeeded', 'failed', 'canceled'].includes(s);

function progressBar(p, big) {
  const bar = el('div', { class: 'bar', style: `width:${pct(p.fraction)}` });
  return el('div', { class: big ? 'progress big' : 'progress', role: 'progressbar',
    'aria-valuenow': Math.round((p.fraction || 0) * 100), 'aria-valuemin': 0, 'aria-valuemax': 100 },
  bar, el('span', { text: pct(p.fraction) }));
}

// ---------- methods ----------
let methodsPromise = null;
function methods() {
  if (!methodsPromise) {
    methodsPromise = apiJson('/v1/methods').catch((e) => { methodsPromise = null; throw e; });
  }
  return methodsPromise;
}

// ---------- server-sent events through fetch ----------
// EventSource cannot send the Authorization header, and the token must never be in a URL, so
// streams are read with fetch() and parsed here (WHATWG HTML §9.2: blocks split by a blank line,
// `event:` names, `data:` lines joined, comments ignored). onEvent(name, data) returning true
// stops reading.
async function readEvents(resp, onEvent) {
  const reader = resp.body.pipeThrough(new TextDecoderStream()).getReader();
  let buf = '';
  for (;;) {
    const { value, done } = await reader.read();
    if (done) return;
    buf += value.replace(/\r\n?/g, '\n');
    let cut;
    while ((cut = buf.indexOf('\n\n')) >= 0) {
      const block = buf.slice(0, cut);
      buf = buf.slice(cut + 2);
      let name = 'message'; const data = [];
      for (const line of block.split('\n')) {
        if (line.startsWith('event:')) name = line.slice(6).trim();
        else if (line.startsWith('data:')) data.push(line.slice(5).replace(/^ /, ''));
      }
      if (!data.length) continue;
      if (await onEvent(name, JSON.parse(data.join('\n')))) { reader.cancel().catch(() => {}); return; }
    }
  }
}

// ---------- jobs list ----------
// Live through one list-level stream (GET /v1/events): rows update in place from `job` events;
// a job not on the page (a new submission) or one that ended reloads the page once (debounced);
// `resync` reloads it. Polling every LIST_POLL_MS only while the stream is down (retried every
// STREAM_RETRY_MS). Ages and durations tick locally.
const list = { cursors: [null], page: 0, timer: null, next: null, jobs: new Map(),
  stream: null, retry: null, reload: null, clock: null, live: false, unknown: new Set(), seq: 0 };

async function loadJobs() {
  const q = new URLSearchParams({ limit: PAGE_SIZE });
  const status = $('filter-status').value;
  const method = $('filter-method').value;
  if (status) q.set('status', status);
  if (method) q.set('method', method);
  const cursor = list.cursors[list.page];
  if (cursor) q.set('next', cursor);
  // Only the newest request renders: an older one (another filter or page, e.g. the stream's
  // `ready` reload still in flight when the filter changed) must not overwrite its rows.
  const seq = ++list.seq;
  const page = await apiJson(`/v1/jobs?${q}`);
  if (seq !== list.seq) return;
  list.next = page.next;
  renderJobs(page.jobs);
  $('page-newer').disabled = list.page === 0;
  $('page-older').disabled = !page.next;
  $('page-number').textContent = `page ${list.page + 1}`;
  $('live').textContent = list.live ? 'live' : `updated ${new Date().toLocaleTimeString()}`;
}

function jobRow(j) {
  return el('tr', { 'data-id': j.id, 'data-status': j.status },
    el('td', {}, el('span', { class: `badge ${j.status}`, text: j.status })),
    el('td', { text: j.method }),
    el('td', { class: 'c-progress' }, progressBar(j.progress),
      el('span', { class: 'stage', text: j.progress.stage || (j.status === 'enqueued' ? 'waiting' : '') })),
    el('td', { class: 'c-age', text: span(secondsSince(j.created_at)), title: j.created_at }),
    el('td', { class: 'c-duration', text: duration(j) }),
    el('td', {}, el('a', { href: `#/jobs/${j.id}`, text: j.id.slice(0, 8) })));
}

function renderJobs(jobs) {
  list.jobs = new Map(jobs.map((j) => [j.id, j]));
  $('job-rows').replaceChildren(...jobs.map(jobRow));
  $('jobs-empty').hidden = jobs.length > 0;
}

function tickClock() {
  for (const tr of $('job-rows').children) {
    const j = list.jobs.get(tr.dataset.id);
    if (!j) continue;
    tr.querySelector('.c-age').textContent = span(secondsSince(j.created_at));
    tr.querySelector('.c-duration').textContent = duration(j);
  }
}

function reloadSoon() {
  clearTimeout(list.reload);
  list.reload = setTimeout(() => {
    loadJobs().then(() => banner('')).catch((e) => { if (e.status !== 401) banner(`Jobs: ${e.message}`); });
  }, 200);
}

// One `job` event (a JobEventDoc): update its row, or reload the page when it is not on it.
function onJobEvent(ev) {
  const j = list.jobs.get(ev.id);
  if (!j) {
    // A job not on this page: new ones show on the first (newest first). Reload once per job,
    // not for every event of a job the page's filter or position keeps off it.
    if (list.page === 0 && !list.unknown.has(ev.id)) { list.unknown.add(ev.id); reloadSoon(); }
    return;
  }
  if (j.revision !== undefined && ev.revision < j.revision && !terminal(ev.status)) return;
  const was = j.status;
  Object.assign(j, { status: ev.status, progress: ev.progress, revision: ev.revision });
  if (ev.status === 'processing' && !j.started_at) j.started_at = new Date().toISOString();
  const tr = $('job-rows').querySelector(`tr[data-id="${ev.id}"]`);
  if (tr) tr.replaceWith(jobRow(j));
  // The end brings a finish time (and may move the job out of a status filter).
  if (terminal(ev.status) && !terminal(was)) reloadSoon();
}

async function openListStream() {
  const ctrl = new AbortController();
  list.stream = ctrl;
  try {
    const resp = await api('/v1/events', { headers: { Accept: 'text/event-stream' }, signal: ctrl.signal });
    await readEvents(resp, async (name, data) => {
      if (list.stream !== ctrl) return true;
      if (name === 'ready') {
        list.live = true;
        clearTimeout(list.timer); list.timer = null; // polling off
        await loadJobs().catch((e) => { if (e.status !== 401) banner(`Jobs: ${e.message}`); });
      } else if (name === 'job') onJobEvent(data);
      else if (name === 'resync') reloadSoon();
      return false;
    });
  } catch (e) {
    if (ctrl.signal.aborted) return;
    if (e.status === 401) { list.stream = null; return; }
  }
  if (list.stream !== ctrl || currentView !== 'jobs') return;
  // The stream failed or ended: poll, and try the stream again later.
  list.live = false;
  list.stream = null;
  startPolling();
  list.retry = setTimeout(() => { if (currentView === 'jobs') openListStream(); }, STREAM_RETRY_MS);
}

function startPolling() {
  clearTimeout(list.timer);
  const tick = async () => {
    try { await loadJobs(); banner(''); } catch (e) { if (e.status !== 401) banner(`Jobs: ${e.message}`); }
    if (currentView === 'jobs' && !list.live) list.timer = setTimeout(tick, LIST_POLL_MS);
  };
  tick();
}

function startList() {
  list.unknown.clear();
  if (list.stream && list.live) {
    // The stream is up: a filter or page change needs just the page.
    loadJobs().catch((e) => { if (e.status !== 401) banner(`Jobs: ${e.message}`); });
    return;
  }
  stopList();
  list.clock = setInterval(tickClock, 1000);
  openListStream();
}
function stopList() {
  list.stream?.abort();
  list.stream = null;
  list.live = false;
  for (const t of [list.timer, list.retry, list.reload]) clearTimeout(t);
  clearInterval(list.clock);
  list.timer = list.retry = list.reload = list.clock = null;
}

function initList() {
  const refilter = () => { list.cursors = [null]; list.page = 0; startList(); };
  $('filter-status').addEventListener('change', refilter);
  $('filter-method').addEventListener('change', refilter);
  $('page-older').addEventListener('click', () => {
    if (!list.next) return;
    list.cursors[list.page + 1] = list.next;
    list.page += 1;
    startList();
  });
  $('page-newer').addEventListener('click', () => { list.page = Math.max(0, list.page - 1); startList(); });
}

// ---------- submit form ----------
const PARTS = {
  target: { label: 'Target model', help: '.glb, or a .gltf with its files, or a .zip' },
  source: { label: 'Source model', help: 'the textured model: .glb, .gltf + files, or .zip' },
  source_base: { label: 'Source base', help: 'a smooth base of the source' },
  pattern: { label: 'Pattern image', help: 'PNG or JPEG', single: true },
  constraints: { label: 'Constraints JSON (optional)', help: 'replaces the form below when given', single: true },
};
const chosen = new Map();
let methodList = [];

function resolve(schema, root) {
  if (schema && schema.$ref && schema.$ref.startsWith('#/$defs/')) {
    return resolve(root.$defs?.[schema.$ref.slice(8)] || {}, root);
  }
  return schema || {};
}

// The choices of a string field (enum, or oneOf/anyOf of consts), or null.
function choices(s, root) {
  if (Array.isArray(s.enum)) return s.enum.map((v) => ({ value: v, help: '' }));
  const alts = s.oneOf || s.anyOf;
  if (Array.isArray(alts)) {
    const r = alts.map((a) => resolve(a, root));
    if (r.every((a) => a.const !== undefined)) return r.map((a) => ({ value: a.const, help: a.description || '' }));
  }
  return null;
}

function typeOf(s) {
  const t = Array.isArray(s.type) ? s.type.filter((x) => x !== 'null') : [s.type];
  return t.length === 1 ? t[0] : null;
}

// One input for a schema property; its wrapper names the API field for server errors.
function fieldFor(path, name, raw, root) {
  const s = resolve(raw, root);
  const wrap = el('div', { class: 'field', 'data-field': `${path}.${name}` });
  const id = `f-${path}-${name}`.replace(/[^A-Za-z0-9_-]/g, '-');
  const label = el('label', { for: id, text: name });
  const help = el('span', { class: 'help', text: (s.description || '').replace(/`/g, '').slice(0, 220) });
  const error = el('span', { class: 'error', hidden: true });
  const t = typeOf(s);
  const opts = choices(s, root);
  let input;
  if (opts) {
    input = el('select', { id, name });
    for (const o of opts) input.append(el('option', { value: JSON.stringify(o.value), text: String(o.value), title: o.help }));
    if (s.default !== undefined) input.value = JSON.stringify(s.default);
    input.dataset.kind = 'json';
  } else if (t === 'integer' || t === 'number') {
    input = el('input', { id, name, type: 'number', step: t === 'integer' ? 1 : 'any',
      min: s.minimum ?? s.exclusiveMinimum, max: s.maximum ?? s.exclusiveMaximum });
    if (typeof s.default === 'number') input.value = s.default;
    input.dataset.kind = t;
  } else if (t === 'boolean') {
    input = el('input', { id, name, type: 'checkbox' });
    input.checked = s.default === true;
    input.dataset.kind = 'boolean';
  } else {
    input = el('textarea', { id, name, rows: 2, placeholder: 'JSON' });
    if (s.default !== undefined && s.default !== null) input.value = JSON.stringify(s.default);
    input.dataset.kind = 'json';
  }
  input.dataset.default = JSON.stringify(s.default ?? null);
  input.schema = s;
  wrap.append(label, input, help, error);
  return wrap;
}

function fieldError(wrap, message) {
  const err = wrap.querySelector('.error');
  if (!err) return;
  wrap.classList.toggle('invalid', !!message);
  err.hidden = !message;
  err.textContent = message || '';
}

// Reads a field: {value} to send, {skip} when at its default/empty, or {error}.
function readField(input) {
  const s = input.schema || {};
  const kind = input.dataset.kind;
  const dflt = input.dataset.default;
  if (kind === 'boolean') {
    return JSON.stringify(input.checked) === dflt ? { skip: true } : { value: input.checked };
  }
  const text = input.value.trim();
  if (text === '') return { skip: true };
  let value;
  if (kind === 'integer' || kind === 'number') {
    value = Number(text);
    if (!Number.isFinite(value)) return { error: 'not a number' };
    if (kind === 'integer' && !Number.isInteger(value)) return { error: 'must be a whole number' };
    if (s.minimum !== undefined && value < s.minimum) return { error: `must be at least ${s.minimum}` };
    if (s.maximum !== undefined && value > s.maximum) return { error: `must be at most ${s.maximum}` };
    if (s.exclusiveMinimum !== undefined && value <= s.exclusiveMinimum) return { error: `must be above ${s.exclusiveMinimum}` };
    if (s.exclusiveMaximum !== undefined && value >= s.exclusiveMaximum) return { error: `must be below ${s.exclusiveMaximum}` };
  } else {
    try { value = JSON.parse(text); } catch { return { error: 'not valid JSON' }; }
  }
  return JSON.stringify(value) === dflt ? { skip: true } : { value };
}

function dropzone(part, use) {
  const spec = PARTS[part];
  const input = el('input', { type: 'file', hidden: true, multiple: !spec.single, 'data-part-input': part });
  const files = el('div', { class: 'files muted', text: 'drop files here or click' });
  const error = el('span', { class: 'error', hidden: true });
  const zone = el('div', { class: 'drop', 'data-part': part, tabindex: 0 },
    el('h3', { text: `${spec.label}${use === 'required' ? ' *' : ''}` }),
    el('div', { class: 'help muted', text: `${spec.help}${use === 'optional' ? ' (optional)' : ''}` }),
    files, error, input);
  const show = () => {
    const list = chosen.get(part) || [];
    files.textContent = list.length ? list.map((f) => `${f.name} (${bytes(f.size)})`).join(', ') : 'drop files here or click';
    zone.classList.remove('invalid');
    error.hidden = true;
  };
  const take = (fl) => { chosen.set(part, spec.single ? [...fl].slice(0, 1) : [...fl]); show(); };
  zone.addEventListener('click', (e) => { if (e.target !== input) input.click(); });
  zone.addEventListener('keydown', (e) => { if (e.key === 'Enter' || e.key === ' ') input.click(); });
  input.addEventListener('change', () => take(input.files));
  zone.addEventListener('dragover', (e) => { e.preventDefault(); zone.classList.add('over'); });
  zone.addEventListener('dragleave', () => zone.classList.remove('over'));
  zone.addEventListener('drop', (e) => { e.preventDefault(); zone.classList.remove('over'); take(e.dataTransfer.files); });
  show();
  return zone;
}

function buildForm() {
  const id = $('method').value;
  const m = methodList.methods.find((x) => x.id === id);
  if (!m) return;
  const zones = [];
  for (const part of ['source', 'target', 'source_base', 'pattern']) {
    const use = m.inputs[part];
    if (use !== 'unused') zones.push(dropzone(part, use));
    else chosen.delete(part);
  }
  zones.push(dropzone('constraints', 'optional'));
  $('dropzones').replaceChildren(...zones);
  const root = methodList.constraints_schema;
  const output = resolve(root.properties?.output, root);
  $('output-fields').replaceChildren(el('legend', { text: 'Output' }),
    ...Object.entries(output.properties || {}).map(([k, v]) => fieldFor('constraints.output', k, v, root)));
  const ps = m.params_schema;
  const props = Object.entries(ps.properties || {});
  $('param-fields').replaceChildren(el('legend', { text: `Parameters of ${id}` }),
    ...props.map(([k, v]) => fieldFor('constraints.params', k, v, ps)));
  if (!props.length) $('param-fields').append(el('p', { class: 'muted', text: 'This method has no parameters.' }));
  $('method-help').textContent = (ps.description || '').replace(/`/g, '');
}

async function showSubmit() {
  try {
    methodList = await methods();
  } catch (e) {
    if (e.status !== 401) banner(`Methods: ${e.message}`);
    return;
  }
  const sel = $('method');
  if (!sel.options.length) {
    for (const m of methodList.methods) sel.append(el('option', { value: m.id, text: m.id }));
    sel.addEventListener('change', buildForm);
    buildForm();
  }
}

function clearErrors() {
  document.querySelectorAll('#submit-form [data-field]').forEach((w) => fieldError(w, ''));
  document.querySelectorAll('#submit-form .drop').forEach((z) => {
    z.classList.remove('invalid');
    z.querySelector('.error').hidden = true;
  });
  $('submit-error').hidden = true;
}

// Shows a problem next to the field it names (`constraints.params.x`, `source`, ...): the
// deepest field whose name is a prefix of it; otherwise above the button.
function showProblem(p) {
  const field = p.field || '';
  const candidates = [...document.querySelectorAll('#submit-form [data-field], #submit-form [data-part]')];
  let best = null;
  for (const c of candidates) {
    const name = c.dataset.field || c.dataset.part;
    if ((field === name || field.startsWith(`${name}.`) || field.startsWith(`${name}[`)) && (!best || name.length > (best.dataset.field || best.dataset.part).length)) best = c;
  }
  const text = `${p.title || 'Error'}: ${p.detail || ''}`;
  if (best && best.classList.contains('field')) { fieldError(best, text); best.querySelector('input,select,textarea')?.focus(); return; }
  if (best) {
    best.classList.add('invalid');
    const e = best.querySelector('.error');
    e.hidden = false; e.textContent = text;
    return;
  }
  $('submit-error').hidden = false;
  $('submit-error').textContent = field ? `${text} (${field})` : text;
}

async function submitJob(ev) {
  ev.preventDefault();
  clearErrors();
  const m = methodList.methods.find((x) => x.id === $('method').value);
  let ok = true;
  const section = (sel) => {
    const out = {};
    for (const wrap of document.querySelectorAll(`${sel} [data-field]`)) {
      const input = wrap.querySelector('input,select,textarea');
      const r = readField(input);
      if (r.error) { fieldError(wrap, r.error); ok = false; } else if (!r.skip) out[input.name] = r.value;
    }
    return out;
  };
  const output = section('#output-fields');
  const params = section('#param-fields');
  for (const part of ['source', 'target', 'source_base', 'pattern']) {
    const use = part === 'target' ? 'required' : m.inputs[part];
    if (use === 'required' && !(chosen.get(part) || []).length) {
      showProblem({ field: part, title: 'Missing file', detail: `${m.id} needs a ${part}` });
      ok = false;
    }
  }
  if (!ok) return;
  const form = new FormData();
  for (const part of ['source', 'target', 'source_base', 'pattern']) {
    for (const f of chosen.get(part) || []) form.append(part, f, f.name);
  }
  const file = (chosen.get('constraints') || [])[0];
  if (file) form.append('constraints', file, file.name);
  else {
    const c = { version: 1, method: m.id };
    if (Object.keys(output).length) c.output = output;
    if (Object.keys(params).length) c.params = params;
    form.append('constraints', new Blob([JSON.stringify(c)], { type: 'application/json' }), 'constraints.json');
  }
  $('submit-button').disabled = true;
  $('submit-status').textContent = 'uploading…';
  try {
    const doc = await apiJson('/v1/jobs', { method: 'POST', body: form });
    location.hash = `#/jobs/${doc.id}`;
  } catch (e) {
    if (e.status !== 401) showProblem(e.problem || { detail: e.message });
  } finally {
    $('submit-button').disabled = false;
    $('submit-status').textContent = '';
  }
}

// ---------- job page ----------
const job = { id: null, doc: null, stream: null, poll: null, urls: [], shown: false };

function release() {
  job.urls.forEach((u) => URL.revokeObjectURL(u));
  job.urls = [];
}

async function blobUrl(path) {
  const b = await (await api(path)).blob();
  const u = URL.createObjectURL(b);
  job.urls.push(u);
  return u;
}

function renderProgress(status, p) {
  $('job-status').className = `badge ${status}`;
  $('job-status').textContent = status;
  $('job-bar').style.width = pct(p.fraction);
  $('job-bar').parentElement.setAttribute('aria-valuenow', Math.round((p.fraction || 0) * 100));
  $('job-bar').parentElement.dataset.status = status;
  $('job-pct').textContent = pct(p.fraction);
  $('job-stage').textContent = p.stage ? `${p.stage} (${p.stages.done}/${p.stages.total} stages)` : '';
  $('job-cancel').disabled = terminal(status);
}

function rows(tbody, pairs) {
  tbody.replaceChildren(...pairs.map(([k, v]) => el('tr', {}, el('td', { text: k }), el('td', { text: v }))));
}

// Flattens the method's figures to (path, value) rows; long arrays are summarised.
function figures(v, prefix = '', out = []) {
  if (out.length > 200) return out;
  if (Array.isArray(v)) {
    if (v.length > 8 || v.some((x) => typeof x === 'object' && x !== null)) out.push([prefix, `[${v.length} items]`]);
    else out.push([prefix, v.map((x) => fmt(x)).join(', ')]);
  } else if (v && typeof v === 'object') {
    for (const [k, x] of Object.entries(v)) figures(x, prefix ? `${prefix}.${k}` : k, out);
  } else out.push([prefix, fmt(v)]);
  return out;
}
const fmt = (x) => typeof x === 'number' && !Number.isInteger(x) ? x.toPrecision(4) : String(x);

function download(name, path) {
  return el('button', { type: 'button', class: 'link-button secondary', 'data-download': name, onclick: async () => {
    try {
      const u = await blobUrl(path);
      const a = el('a', { href: u, download: name });
      document.body.append(a); a.click(); a.remove();
    } catch (e) { banner(`Download: ${e.message}`); }
  } }, name);
}

async function renderJob(doc) {
  job.doc = doc;
  $('job-id').textContent = doc.id;
  $('job-method').textContent = doc.method;
  renderProgress(doc.status, doc.progress);
  $('job-error').hidden = !doc.error;
  if (doc.error) $('job-error').textContent = `${doc.error.title}: ${doc.error.detail}${doc.error.field ? ` (${doc.error.field})` : ''}`;
  const r = doc.report || {};
  rows($('job-timings'), (r.timings || []).map((t) => [t.stage, `${t.ms.toFixed(0)} ms`]));
  const warnings = [...(r.source_warnings || []), ...(r.target_warnings || []), ...(r.warnings || [])];
  $('job-warnings').replaceChildren(...(warnings.length ? warnings.map((w) => el('li', { text: w })) : [el('li', { class: 'muted', text: 'none' })]));
  rows($('job-figures'), figures(r.method_report || {}));
  const files = [];
  if (doc.status === 'succeeded') files.push(el('li', {}, download(`retex-${doc.id.slice(0, 8)}.glb`, doc.links.result), ' result model'));
  for (const a of doc.links.artifacts) files.push(el('li', {}, download(a.name, a.href), ` ${a.media_type}, ${bytes(a.size)}`));
  $('job-files').replaceChildren(...(files.length ? files : [el('li', { class: 'muted', text: 'none yet' })]));
  if (doc.status === 'succeeded' && !job.shown) {
    job.shown = true;
    showResult(doc);
  }
}

async function showResult(doc) {
  const names = new Set(doc.links.artifacts.map((a) => a.name));
  for (const [name, id] of [['preview.png', 'preview-result'], ['source_preview.png', 'preview-source'], ['target_preview.png', 'preview-target']]) {
    const img = $(id);
    if (!names.has(name)) { img.hidden = true; continue; }
    blobUrl(`/v1/jobs/${doc.id}/artifacts/${name}`).then((u) => { img.src = u; img.hidden = false; }).catch(() => {});
  }
  try {
    const u = await blobUrl(doc.links.result);
    const v = $('viewer');
    v.hidden = false;
    v.src = u;
    $('viewer-note').textContent = 'Drag to turn, scroll to zoom.';
  } catch (e) {
    $('viewer-note').textContent = `The model could not be loaded: ${e.message}`;
  }
}

// Server-sent events read through fetch (EventSource cannot send the Authorization header).
async function follow(id) {
  const ctrl = new AbortController();
  job.stream = ctrl;
  try {
    const resp = await api(`/v1/jobs/${id}/events`, { headers: { Accept: 'text/event-stream' }, signal: ctrl.signal });
    let ended = false;
    await readEvents(resp, (name, ev) => {
      if (job.id !== id) return true;
      renderProgress(ev.status, ev.progress);
      ended = name === 'done';
      return ended;
    });
    if (ended) ctrl.abort();
    if (job.id === id) await refreshJob(id);
  } catch (e) {
    if (ctrl.signal.aborted || job.id !== id) return;
    pollJob(id); // fallback
  }
}

function pollJob(id) {
  clearTimeout(job.poll);
  job.poll = setTimeout(async () => {
    if (job.id !== id) return;
    const doc = await refreshJob(id).catch(() => null);
    if (!doc || !terminal(doc.status)) pollJob(id);
  }, 1000);
}

async function refreshJob(id) {
  const doc = await apiJson(`/v1/jobs/${id}`);
  if (job.id === id) await renderJob(doc);
  return doc;
}

function leaveJob() {
  job.stream?.abort();
  clearTimeout(job.poll);
  job.id = null;
  // Nothing of this job may show on the next one's page before it loads.
  $('job-status').textContent = '';
  $('job-status').className = 'badge';
  job.shown = false;
  release();
  const v = $('viewer');
  v.removeAttribute('src'); v.hidden = true;
  for (const i of ['preview-result', 'preview-source', 'preview-target']) { $(i).hidden = true; $(i).removeAttribute('src'); }
}

async function showJob(id) {
  job.id = id;
  $('job-constraints').textContent = '';
  try {
    const doc = await refreshJob(id);
    apiJson(`/v1/jobs/${id}/constraints`).then((c) => { $('job-constraints').textContent = JSON.stringify(c, null, 2); }).catch(() => {});
    if (!terminal(doc.status)) follow(id);
  } catch (e) {
    if (e.status !== 401) banner(`Job: ${e.message}`);
  }
}

function initJob() {
  $('job-cancel').addEventListener('click', async () => {
    try { await api(`/v1/jobs/${job.id}/cancel`, { method: 'POST' }); await refreshJob(job.id); } catch (e) { banner(`Cancel: ${e.message}`); }
  });
  $('job-delete').addEventListener('click', async () => {
    if (!confirm('Delete this job and its files?')) return;
    try { await api(`/v1/jobs/${job.id}`, { method: 'DELETE' }); location.hash = '#/'; } catch (e) { banner(`Delete: ${e.message}`); }
  });
  $('copy-constraints').addEventListener('click', async () => {
    const text = $('job-constraints').textContent;
    try { await navigator.clipboard.writeText(text); } catch {
      const r = document.createRange(); r.selectNodeContents($('job-constraints'));
      getSelection().removeAllRanges(); getSelection().addRange(r);
    }
  });
}

// ---------- routing ----------
let currentView = null;
function route() {
  const hash = location.hash || '#/';
  const m = hash.match(/^#\/jobs\/([0-9a-fA-F-]{36})$/);
  const view = m ? 'job' : hash === '#/submit' ? 'submit' : 'jobs';
  if (currentView === 'job' && (view !== 'job' || m[1] !== job.id)) leaveJob();
  currentView = view;
  banner('');
  for (const v of ['jobs', 'submit', 'job']) $(`view-${v}`).hidden = v !== view;
  document.querySelectorAll('[data-nav]').forEach((a) => a.classList.toggle('active', a.dataset.nav === view));
  if (view !== 'jobs') stopList();
  if (view === 'jobs') {
    methods().then((ml) => {
      const sel = $('filter-method');
      if (sel.options.length === 1) for (const x of ml.methods) sel.append(el('option', { value: x.id, text: x.id }));
    }).catch(() => {});
    startList();
  } else if (view === 'submit') showSubmit();
  else showJob(m[1]);
}

initLogin();
initList();
initJob();
$('submit-form').addEventListener('submit', submitJob);
window.addEventListener('hashchange', route);
route();
