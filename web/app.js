// cellcal cockpit: a thin client of the REST API (see /api/openapi.json). Plain JS, no build step.
'use strict';

const TOKEN_KEY = 'cellcal.token';
const TERMINAL = ['done', 'aborted', 'failed'];
const $ = (id) => document.getElementById(id);

const ui = {
  token: null,
  me: null,            // {name, role, may: [action…]}
  selected: null,      // campaign id
  view: null,          // the selected campaign's view
  promptSeq: null,     // seq of the question on screen
  answered: new Set(), // seqs answered from this page
  resultFor: null,     // campaign id whose result is on screen
  follow: null,        // {id, ctrl}
  lastSeq: new Map(),  // campaign id → last journal seq seen
  samples: [],         // [{t, done}] for the time left
  refreshing: false,
  again: false,
};

/** The token from `?token=` (moved to sessionStorage and removed from the address bar), or the stored one. */
function takeToken() {
  const url = new URL(window.location.href);
  const fromLink = url.searchParams.get('token');
  if (fromLink) {
    sessionStorage.setItem(TOKEN_KEY, fromLink);
    url.searchParams.delete('token');
    history.replaceState(null, '', url.pathname + url.search + url.hash);
  }
  return sessionStorage.getItem(TOKEN_KEY);
}

class ApiError extends Error {
  constructor(status, message) { super(message); this.status = status; }
}

/** One API call with the bearer token; the parsed JSON body, or an ApiError with the server's message. */
async function api(method, path, body) {
  const headers = { Authorization: 'Bearer ' + ui.token };
  const init = { method, headers };
  if (body !== undefined) {
    headers['Content-Type'] = 'application/json';
    init.body = JSON.stringify(body);
  }
  const r = await fetch(path, init);
  let data = null;
  try { data = await r.json(); } catch (_) { data = null; }
  if (!r.ok) {
    if (r.status === 401) signOut((data && data.error) || 'not signed in');
    throw new ApiError(r.status, (data && data.error) || ('HTTP ' + r.status));
  }
  return data;
}

function may(action) { return !!ui.me && ui.me.may.includes(action); }

function say(text) { $('message').textContent = text || ''; }

function signOut(why) {
  sessionStorage.removeItem(TOKEN_KEY);
  ui.token = null;
  ui.me = null;
  stopFollowing();
  $('app').hidden = true;
  $('sign-out').hidden = true;
  $('who').textContent = '';
  $('sign-in').hidden = false;
  $('sign-in-error').textContent = why || '';
}

async function signIn(token) {
  ui.token = token;
  try {
    ui.me = await api('GET', '/api/whoami');
  } catch (e) {
    if (e.status !== 401) signOut(e.message);
    return;
  }
  sessionStorage.setItem(TOKEN_KEY, token);
  $('sign-in').hidden = true;
  $('app').hidden = false;
  $('sign-out').hidden = false;
  $('who').textContent = ui.me.name + ' (' + ui.me.role + ')';
  for (const el of document.querySelectorAll('[data-action]')) {
    el.hidden = !may(el.dataset.action);
  }
  await refresh();
}

// ---- campaigns -------------------------------------------------------------------------

function cell(row, text) {
  const td = document.createElement('td');
  td.textContent = text;
  row.appendChild(td);
}

function renderList(list) {
  const body = $('campaign-list').tBodies[0];
  body.replaceChildren();
  for (const c of list) {
    const tr = document.createElement('tr');
    tr.dataset.id = c.id;
    if (c.id === ui.selected) tr.className = 'selected';
    for (const t of [c.id, c.name, c.state, c.poses_done + ' / ' + c.poses_total, c.model,
      c.has_result ? (c.quality || 'yes') : '']) cell(tr, String(t));
    tr.addEventListener('click', () => select(c.id));
    body.appendChild(tr);
  }
}

function select(id) {
  if (ui.selected !== id) {
    ui.selected = id;
    ui.samples = [];
    ui.resultFor = null;
    $('result-view').hidden = true;
    $('event-log').replaceChildren();
    stopFollowing();
  }
  refresh();
}

/** The campaign to show when none is chosen: the loaded one, else the newest. */
function defaultSelection(list) {
  const loaded = list.find((c) => c.loaded);
  if (loaded) return loaded.id;
  return list.length ? list[list.length - 1].id : null;
}

async function refresh() {
  if (!ui.me) return;
  if (ui.refreshing) { ui.again = true; return; }
  ui.refreshing = true;
  try {
    const list = await api('GET', '/api/campaigns');
    list.sort((a, b) => a.id - b.id);
    if (ui.selected === null || !list.some((c) => c.id === ui.selected)) ui.selected = defaultSelection(list);
    renderList(list);
    if (ui.selected !== null) {
      const view = await api('GET', '/api/campaigns/' + ui.selected);
      renderView(view);
      if (view.has_result && ui.resultFor !== view.id) await showResult(view.id);
      if (view.loaded) ensureFollowing(view.id);
    } else {
      renderView(null);
    }
  } catch (e) {
    say(e.message);
  } finally {
    ui.refreshing = false;
    if (ui.again) { ui.again = false; refresh(); }
  }
}

function renderView(v) {
  ui.view = v;
  $('campaign-id').textContent = v ? '#' + v.id + ' ' + v.name : '(none)';
  $('campaign-state').textContent = v ? v.state : '—';
  $('armed-flag').textContent = v && v.armed ? 'ARMED — the robot may move' : '';
  const done = v ? v.poses_done : 0;
  const total = v ? v.poses_total : 0;
  $('progress').textContent = done + ' / ' + total;
  $('progress-bar').max = Math.max(total, 1);
  $('progress-bar').value = done;
  $('time-left').textContent = timeLeft(v);
  const state = v ? v.state : '';
  const terminal = state === 'done';
  $('cmd-arm').disabled = !v || v.armed || terminal;
  $('cmd-disarm').disabled = !v || !v.armed;
  $('cmd-start').disabled = !v || !v.armed || ['running', 'paused', 'identifying', 'done'].includes(state);
  $('cmd-pause').disabled = !v || state !== 'running';
  $('cmd-resume').disabled = !v || state !== 'paused';
  renderPrompt(v);
}

/** "about 3 min left" from the poses measured while this page watched. */
function timeLeft(v) {
  if (!v || v.state !== 'running') { if (v && TERMINAL.includes(v.state)) ui.samples = []; return ''; }
  const now = Date.now();
  const last = ui.samples[ui.samples.length - 1];
  if (!last || last.done !== v.poses_done) ui.samples.push({ t: now, done: v.poses_done });
  if (ui.samples.length > 30) ui.samples.shift();
  const first = ui.samples[0];
  const newest = ui.samples[ui.samples.length - 1];
  if (ui.samples.length < 2 || newest.done <= first.done) return 'time left: estimating…';
  const perPose = (newest.t - first.t) / (newest.done - first.done);
  const s = Math.round((perPose * (v.poses_total - v.poses_done)) / 1000);
  return 'time left: about ' + (s < 120 ? s + ' s' : Math.round(s / 60) + ' min');
}

// ---- technician panel ------------------------------------------------------------------

function renderPrompt(v) {
  const q = v && v.prompt && !ui.answered.has(v.prompt.seq) ? v.prompt : null;
  const panel = $('prompt-panel');
  if (!q) {
    panel.hidden = true;
    ui.promptSeq = null;
    return;
  }
  if (q.seq === ui.promptSeq) return;
  ui.promptSeq = q.seq;
  panel.dataset.seq = q.seq;
  const pose = Math.min(v.poses_done + 1, v.poses_total);
  $('prompt-context').textContent = 'Pose ' + pose + ' of ' + v.poses_total + ' · question ' + q.seq + ' (' + q.id + ')'
    + (q.expected_mm != null ? ' · expected about ' + q.expected_mm.toFixed(3) + ' mm' : '');
  $('prompt-safe').textContent = 'Robot stopped — waiting for your answer, safe to approach the stage.';
  $('prompt-text').textContent = q.text;
  $('prompt-error').textContent = '';
  const numeric = q.expected_mm != null;
  const canAnswer = may('answer');
  $('prompt-value').value = '';
  $('prompt-value').hidden = !numeric || !canAnswer;
  document.querySelector('label[for=prompt-value]').hidden = !numeric || !canAnswer;
  $('prompt-confirm').hidden = !canAnswer;
  panel.hidden = false;
  panel.classList.remove('fresh');
  void panel.offsetWidth;
  panel.classList.add('fresh');
  if (canAnswer) (numeric ? $('prompt-value') : $('prompt-confirm')).focus();
}

/** A typed reading in mm: `10.003` or `10,003`; null when it is not a plain decimal number. */
function parseReading(text) {
  const t = text.trim().replace(',', '.');
  if (!/^[+-]?(\d+(\.\d*)?|\.\d+)$/.test(t)) return null;
  const x = Number(t);
  return Number.isFinite(x) ? x : null;
}

async function confirmPrompt(ev) {
  ev.preventDefault();
  const v = ui.view;
  if (!v || !v.prompt || ui.promptSeq === null) return;
  const seq = ui.promptSeq;
  const body = { command: 'answer', seq };
  if (v.prompt.expected_mm != null) {
    const x = parseReading($('prompt-value').value);
    if (x === null) {
      $('prompt-error').textContent = 'Type the reading in mm, e.g. 10.003 or 10,003.';
      $('prompt-value').focus();
      return;
    }
    body.value_mm = x;
  }
  try {
    await commandOn(v.id, body);
    ui.answered.add(seq);
    $('prompt-panel').hidden = true;
    ui.promptSeq = null;
  } catch (e) {
    $('prompt-error').textContent = e.message;
  }
  refresh();
}

// ---- commands --------------------------------------------------------------------------

async function commandOn(id, body) {
  const view = await api('POST', '/api/campaigns/' + id + '/commands', body);
  if (view && view.id === ui.selected) renderView(view);
  return view;
}

async function command(name) {
  if (ui.selected === null) return;
  say('');
  try {
    await commandOn(ui.selected, { command: name });
  } catch (e) {
    say(name + ': ' + e.message);
  }
  refresh();
}

/** Abort whatever can move: the loaded campaign, else the selected one. Never asks. */
async function abortNow() {
  say('');
  let id = ui.selected;
  try {
    const list = await api('GET', '/api/campaigns');
    const loaded = list.find((c) => c.loaded);
    if (loaded) id = loaded.id;
  } catch (_) { /* abort the selected one */ }
  if (id === null) { say('nothing to abort'); return; }
  try {
    await commandOn(id, { command: 'abort' });
    say('Aborted: the robot was told to stop.');
  } catch (e) {
    say('abort: ' + e.message);
  }
  refresh();
}

async function create(ev) {
  ev.preventDefault();
  const body = {};
  for (const k of ['poses', 'ident', 'seed']) {
    const raw = $('create-' + k).value.trim();
    if (raw !== '') body[k] = Number(raw);
  }
  if ($('create-model').value) body.model = $('create-model').value;
  say('');
  try {
    const view = await api('POST', '/api/campaigns', body);
    select(view.id);
  } catch (e) {
    say('create: ' + e.message);
  }
}

// ---- live events (fetch streaming: EventSource cannot send the bearer header) -----------

function stopFollowing() {
  if (ui.follow) ui.follow.ctrl.abort();
  ui.follow = null;
}

function ensureFollowing(id) {
  if (ui.follow && ui.follow.id === id) return;
  stopFollowing();
  const f = { id, ctrl: new AbortController() };
  ui.follow = f;
  followStream(f).finally(() => { if (ui.follow === f) ui.follow = null; });
}

async function followStream(f) {
  const headers = { Authorization: 'Bearer ' + ui.token };
  const last = ui.lastSeq.get(f.id);
  headers['Last-Event-ID'] = String(last === undefined ? 0 : last);
  let r;
  try {
    r = await fetch('/api/campaigns/' + f.id + '/stream', { headers, signal: f.ctrl.signal });
  } catch (_) { return; }
  if (!r.ok || !r.body) return;
  const reader = r.body.pipeThrough(new TextDecoderStream()).getReader();
  let buf = '';
  try {
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buf += value.replace(/\r\n?/g, '\n');
      let end;
      while ((end = buf.indexOf('\n\n')) >= 0) {
        onSse(f.id, buf.slice(0, end));
        buf = buf.slice(end + 2);
      }
    }
  } catch (_) { /* aborted or dropped: the next refresh follows again from the last id */ }
}

function onSse(id, block) {
  let seq = null; let kind = 'message'; const data = [];
  for (const line of block.split('\n')) {
    if (line.startsWith(':')) continue;
    const i = line.indexOf(':');
    const field = i < 0 ? line : line.slice(0, i);
    const value = i < 0 ? '' : line.slice(i + 1).replace(/^ /, '');
    if (field === 'id') seq = Number(value);
    else if (field === 'event') kind = value;
    else if (field === 'data') data.push(value);
  }
  if (!data.length) return;
  if (seq !== null && Number.isFinite(seq)) ui.lastSeq.set(id, seq);
  if (id === ui.selected) logEvent(seq, kind, data.join('\n'));
  refresh();
}

function summary(kind, text) {
  let d;
  try { d = JSON.parse(text); } catch (_) { return text; }
  switch (kind) {
    case 'state': return (d.state && (d.state.state || d.state)) + '';
    case 'measured': return 'pose ' + d.pose + ' measured (' + d.done + ' / ' + d.total + ')';
    case 'prompt': return 'question ' + d.seq + ': ' + d.text;
    case 'note': return d.text;
    case 'fault': return d.device + ' ' + d.kind + ': ' + d.message + ' → ' + d.action;
    case 'drift': return 'drift ' + Number(d.drift_mm).toFixed(4) + ' mm (max ' + d.max_mm + ')';
    case 'result': return 'result: quality ' + ((d.json && d.json.quality) || '—');
    default: return text.length > 200 ? text.slice(0, 200) + '…' : text;
  }
}

function logEvent(seq, kind, text) {
  const li = document.createElement('li');
  li.textContent = (seq !== null ? '#' + seq + ' ' : '') + kind + ': ' + summary(kind, text);
  const log = $('event-log');
  log.prepend(li);
  while (log.children.length > 500) log.lastElementChild.remove();
}

// ---- result ----------------------------------------------------------------------------

function fmt(x, digits) { return typeof x === 'number' && Number.isFinite(x) ? x.toFixed(digits) : '—'; }

async function showResult(id) {
  let r;
  try { r = await api('GET', '/api/campaigns/' + id + '/result'); } catch (e) { say('result: ' + e.message); return; }
  if (id !== ui.selected) return;
  ui.resultFor = id;
  const q = typeof r.quality === 'string' ? r.quality : 'not given';
  $('quality').textContent = q;
  $('quality').className = q;
  const warnings = $('warnings');
  warnings.replaceChildren();
  for (const w of Array.isArray(r.warnings) ? r.warnings : []) {
    const li = document.createElement('li');
    li.textContent = typeof w === 'string' ? w : ((w.code ? w.code + ': ' : '') + (w.message || JSON.stringify(w)));
    warnings.appendChild(li);
  }
  const mbody = $('result-metrics').tBodies[0];
  mbody.replaceChildren();
  const metrics = r.metrics || {};
  for (const set of ['ident', 'verify']) {
    const m = metrics[set];
    if (!m || !m.before || !m.after) continue;
    const tr = document.createElement('tr');
    cell(tr, set);
    cell(tr, String(m.after.poses));
    for (const k of ['position_mean_mm', 'position_p95_mm', 'position_max_mm']) {
      cell(tr, fmt(m.before[k], 4));
      cell(tr, fmt(m.after[k], 4));
      if (set === 'verify' && k === 'position_mean_mm') tr.lastChild.id = 'result-verify-after';
    }
    mbody.appendChild(tr);
  }
  const pbody = $('result-parameters').tBodies[0];
  pbody.replaceChildren();
  for (const p of Array.isArray(r.parameters) ? r.parameters : []) {
    const tr = document.createElement('tr');
    const digits = p.unit === 'rad' ? 7 : 4;
    cell(tr, p.name);
    cell(tr, p.unit);
    cell(tr, fmt(p.nominal, digits));
    cell(tr, fmt(p.error, digits));
    cell(tr, p.std == null ? '—' : fmt(p.std, digits));
    cell(tr, p.identified ? 'yes' : 'no');
    pbody.appendChild(tr);
  }
  const ni = $('not-identifiable');
  ni.replaceChildren();
  for (const d of Array.isArray(r.not_identifiable) ? r.not_identifiable : []) {
    const li = document.createElement('li');
    li.textContent = d.name + ': ' + d.reason;
    ni.appendChild(li);
  }
  if (!ni.children.length) ni.textContent = 'none';
  $('result-view').hidden = false;
}

/** Save an API document as a file (a plain link could not send the bearer header). */
async function download(path, name) {
  try {
    const data = await api('GET', path);
    const url = URL.createObjectURL(new Blob([JSON.stringify(data, null, 2)], { type: 'application/json' }));
    const a = document.createElement('a');
    a.href = url;
    a.download = name;
    a.click();
    setTimeout(() => URL.revokeObjectURL(url), 1000);
  } catch (e) {
    say(e.message);
  }
}

// ---- wiring ----------------------------------------------------------------------------

function askAbort() { $('abort-dialog').showModal(); $('abort-cancel').focus(); }

function wire() {
  $('sign-in-form').addEventListener('submit', (ev) => { ev.preventDefault(); signIn($('token-input').value.trim()); });
  $('sign-out').addEventListener('click', () => signOut(''));
  $('abort').addEventListener('click', abortNow);
  $('create-form').addEventListener('submit', create);
  $('prompt-form').addEventListener('submit', confirmPrompt);
  $('prompt-abort').addEventListener('click', askAbort);
  $('cmd-arm').addEventListener('click', () => { $('arm-dialog').showModal(); $('arm-cancel').focus(); });
  $('arm-confirm').addEventListener('click', () => { $('arm-dialog').close(); command('arm'); });
  $('arm-cancel').addEventListener('click', () => $('arm-dialog').close());
  $('abort-confirm').addEventListener('click', () => { $('abort-dialog').close(); abortNow(); });
  $('abort-cancel').addEventListener('click', () => { $('abort-dialog').close(); if (!$('prompt-panel').hidden) $('prompt-value').focus(); });
  for (const name of ['disarm', 'start', 'pause', 'resume']) {
    $('cmd-' + name).addEventListener('click', () => command(name));
  }
  $('download-result').addEventListener('click', () => download('/api/campaigns/' + ui.selected + '/result', 'campaign-' + ui.selected + '-result.json'));
  $('download-events').addEventListener('click', () => download('/api/campaigns/' + ui.selected + '/events', 'campaign-' + ui.selected + '-events.json'));
  document.addEventListener('keydown', (ev) => {
    if (ev.key === 'Escape' && !$('prompt-panel').hidden && !$('abort-dialog').open) {
      ev.preventDefault();
      askAbort();
    }
  });
  setInterval(refresh, 1000);
}

wire();
const stored = takeToken();
if (stored) signIn(stored); else signOut('');
