// cellcal cockpit: a thin client of the REST API (see /api/openapi.json). Plain JS, no build step.
// Every number and time on the page goes through `human` (human.js, loaded first).
'use strict';

const TOKEN_KEY = 'cellcal.token';
const SOUND_KEY = 'cellcal.sound';
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
  samples: [],         // [{t, done}] for the time left
  refreshing: false,
  again: false,
  historyFor: null,    // campaign id whose stored journal was read
  seenSeq: 0,          // highest journal seq shown for the selected campaign
  measured: [],        // [{done, total, pose, dev}] of the selected campaign ('measured' events)
  drifts: [],          // [{after, drift_mm, max_mm}] of the selected campaign ('drift' events)
  listKey: '',         // the campaign list as last drawn
  plotTotal: null,     // poses_total the plot's x axis was drawn for
  audio: null,         // the WebAudio context of the question beep
  beeps: 0,
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

/** One API call with the bearer token: the response when it succeeded, else an ApiError with
 *  the server's message. */
async function call(method, path, body) {
  const headers = { Authorization: 'Bearer ' + ui.token };
  const init = { method, headers };
  if (body !== undefined) {
    headers['Content-Type'] = 'application/json';
    init.body = JSON.stringify(body);
  }
  const r = await fetch(path, init);
  if (r.ok) return r;
  let data = null;
  try { data = await r.json(); } catch (_) { data = null; }
  if (r.status === 401) signOut((data && data.error) || 'not signed in');
  throw new ApiError(r.status, (data && data.error) || ('HTTP ' + r.status));
}

/** One API call with the bearer token; the parsed JSON body (null for none), or an ApiError. */
async function api(method, path, body) {
  const r = await call(method, path, body);
  try { return await r.json(); } catch (_) { return null; }
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
  pollDevices();
  await refresh();
}

// ---- campaigns -------------------------------------------------------------------------

function cell(row, text) {
  const td = document.createElement('td');
  td.textContent = text;
  row.appendChild(td);
}

/** The campaign table; a row is chosen by click, or by Enter when it has the focus. */
function renderList(list) {
  const key = JSON.stringify([ui.selected, list]);
  if (key === ui.listKey) return;
  ui.listKey = key;
  const body = $('campaign-list').tBodies[0];
  const focused = document.activeElement && document.activeElement.parentNode === body
    ? document.activeElement.dataset.id : null;
  body.replaceChildren();
  for (const c of list) {
    const tr = document.createElement('tr');
    tr.dataset.id = c.id;
    tr.tabIndex = 0;
    if (c.id === ui.selected) tr.className = 'selected';
    for (const t of [c.id, c.name, c.state, c.poses_done + ' / ' + c.poses_total, c.model,
      c.has_result ? (c.quality || 'yes') : '']) cell(tr, String(t));
    tr.addEventListener('click', () => select(c.id));
    tr.addEventListener('keydown', (ev) => { if (ev.key === 'Enter') { ev.preventDefault(); select(c.id); } });
    body.appendChild(tr);
    if (String(c.id) === focused) tr.focus();
  }
}

function select(id) {
  if (ui.selected !== id) {
    ui.selected = id;
    forgetCampaign();
    stopFollowing();
  }
  refresh();
}

/** Clear what the page shows of the previously selected campaign (its events are read again). */
function forgetCampaign() {
  ui.samples = [];
  ui.resultFor = null;
  ui.historyFor = null;
  ui.seenSeq = 0;
  ui.measured = [];
  ui.drifts = [];
  $('result-view').hidden = true;
  $('event-log').replaceChildren();
  renderDrift();
  renderDeviation();
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
    if (ui.selected === null || !list.some((c) => c.id === ui.selected)) {
      ui.selected = defaultSelection(list);
      forgetCampaign();
    }
    renderList(list);
    if (ui.selected !== null) {
      const view = await api('GET', '/api/campaigns/' + ui.selected);
      renderView(view);
      if (ui.historyFor !== view.id) await readHistory(view.id);
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
  renderTime(v);
  if (total !== ui.plotTotal) { ui.plotTotal = total; renderDeviation(); }
  const state = v ? v.state : '';
  const terminal = state === 'done';
  $('cmd-arm').disabled = !v || v.armed || terminal;
  $('cmd-disarm').disabled = !v || !v.armed;
  $('cmd-start').disabled = !v || !v.armed || ['running', 'paused', 'identifying', 'done'].includes(state);
  $('cmd-pause').disabled = !v || state !== 'running';
  // a disarmed campaign resumes only once armed again (the API answers 409)
  $('cmd-resume').disabled = !v || state !== 'paused' || !v.armed;
  renderDownloads(v);
  renderPrompt(v);
}

/** The campaign's planned time (the estimate stored with it) and, once it has run, the time
 *  it took: elapsed against planned while it runs, planned against actual once identified. */
function renderTime(v) {
  const e = v ? v.estimate : null;
  $('campaign-estimate').textContent = e ? e.summary : (v ? 'not estimated' : '—');
  $('campaign-time').textContent = campaignTime(v, e);
}

/** "measuring 12 min 05 s of about 3 h 10 min planned · about 2 h 58 min left by the plan",
 *  or after: "planned 3 h 10 min, took 3 h 22 min measuring (1.06 × planned)"; pauses apart. */
function campaignTime(v, e) {
  if (!v || !(v.measuring_s > 0 || v.paused_s > 0)) return '';
  const paused = v.paused_s > 0 ? ' · paused ' + human.duration(v.paused_s) : '';
  const measuring = human.duration(v.measuring_s);
  if (['identifying', 'done'].includes(v.state)) {
    if (!e) return 'took ' + measuring + ' measuring' + paused;
    return 'planned ' + human.duration(e.total_s) + ', took ' + measuring + ' measuring ('
      + human.ratio(v.measuring_s / e.total_s) + ' × planned)' + paused;
  }
  let text = 'measuring ' + measuring;
  if (e) {
    text += ' of about ' + human.duration(e.total_s) + ' planned';
    if (v.poses_total > 0) {
      // the plan's time per pose (setup apart) for the poses not measured yet
      const left = ((e.total_s - e.setup_s) / v.poses_total) * (v.poses_total - v.poses_done);
      text += ' · about ' + human.duration(Math.max(left, 0)) + ' left by the plan';
    }
  }
  return text + paused;
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
  return 'time left: about ' + human.duration((perPose * (v.poses_total - v.poses_done)) / 1000);
}

// ---- technician panel ------------------------------------------------------------------

function renderPrompt(v) {
  const q = v && v.prompt && !ui.answered.has(v.prompt.seq) ? v.prompt : null;
  const panel = $('prompt-panel');
  if (!q) {
    panel.hidden = true;
    ui.promptSeq = null;
    document.title = 'cellcal — calibration cell';
    return;
  }
  if (q.seq === ui.promptSeq) return;
  ui.promptSeq = q.seq;
  panel.dataset.seq = q.seq;
  $('prompt-context').textContent = promptContext(q);
  const safe = $('prompt-safe');
  safe.textContent = q.robot_stopped === true
    ? 'Robot stopped — safe to approach.'
    : 'Robot state not known — check that the robot stands still before approaching.';
  safe.className = q.robot_stopped === true ? 'safe' : 'safe unknown';
  const retry = $('prompt-retry');
  retry.textContent = q.retry_reason ? 'Not accepted: ' + q.retry_reason + '.' : '';
  retry.hidden = !q.retry_reason;
  $('prompt-text').textContent = q.retry_reason && q.text.startsWith(q.retry_reason)
    ? q.text.slice(q.retry_reason.length).replace(/^[.\s]+/, '') : q.text;
  $('prompt-error').textContent = '';
  const numeric = q.expected_mm != null;
  const canAnswer = may('answer');
  // the question that releases the robot is answered only by its own button, never by Enter
  const clear = q.id === 'confirm_clear';
  $('prompt-value').value = '';
  $('prompt-value').hidden = !numeric || !canAnswer || clear;
  document.querySelector('label[for=prompt-value]').hidden = !numeric || !canAnswer || clear;
  $('prompt-confirm').hidden = !canAnswer || clear;
  $('prompt-clear').hidden = !canAnswer || !clear;
  $('prompt-hint').hidden = !canAnswer || clear;
  panel.hidden = false;
  cue(panel);
  if (canAnswer && !clear) (numeric ? $('prompt-value') : $('prompt-confirm')).focus();
  if (clear && document.activeElement) document.activeElement.blur();
}

/** "Pose 3 of 20 · P2 · question 7": what the question is about, from the engine's context only. */
function promptContext(q) {
  const parts = [];
  if (q.pose != null && q.poses_total != null) parts.push('Pose ' + q.pose + ' of ' + q.poses_total);
  else if (q.step === 'drift') parts.push('Drift check at the reference pose');
  else if (q.step === 'setup') parts.push('Setup (tool frame, base registration)');
  else if (q.step === 'reregister') parts.push('Re-registering the tracker frame');
  if (q.position) parts.push(q.position);
  if (q.expected_mm != null) parts.push('set to ' + human.mm(q.expected_mm) + ' mm');
  parts.push('question ' + q.seq);
  return parts.join(' · ');
}

/** A question opened: flash the panel, bring it into view, mark the tab title, beep if asked. */
function cue(panel) {
  panel.classList.remove('fresh');
  void panel.offsetWidth;
  panel.classList.add('fresh');
  panel.scrollIntoView({ block: 'start' });
  document.title = '▶ Question — cellcal';
  if (!$('sound-toggle').checked) return;
  try {
    if (!ui.audio) ui.audio = new AudioContext();
    const a = ui.audio;
    if (a.state === 'suspended') a.resume();
    const osc = a.createOscillator();
    const gain = a.createGain();
    osc.frequency.value = 880;
    gain.gain.setValueAtTime(0.25, a.currentTime);
    gain.gain.exponentialRampToValueAtTime(0.001, a.currentTime + 0.35);
    osc.connect(gain).connect(a.destination);
    osc.start();
    osc.stop(a.currentTime + 0.35);
    ui.beeps += 1;
    panel.dataset.beeps = ui.beeps;
  } catch (_) { /* no audio device: the visual cue stands */ }
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
  // Enter never releases the robot: the confirm_clear question takes only its button
  if (v.prompt.id === 'confirm_clear') return;
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
  await answerWith(v.id, seq, body);
}

/** Send the answer `body` to question `seq` of campaign `id`; the panel closes once taken. */
async function answerWith(id, seq, body) {
  try {
    await commandOn(id, body);
    ui.answered.add(seq);
    $('prompt-panel').hidden = true;
    ui.promptSeq = null;
  } catch (e) {
    $('prompt-error').textContent = e.message;
  }
  refresh();
}

/** The technician confirms the cell clear (its own button): the robot may move again. */
async function confirmClear() {
  const v = ui.view;
  if (!v || !v.prompt || v.prompt.id !== 'confirm_clear' || ui.promptSeq === null) return;
  const seq = ui.promptSeq;
  await answerWith(v.id, seq, { command: 'confirm_clear', seq });
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

/** Stop the cell (POST /api/cell/stop): the loaded campaign aborts, robot and stage stop. Never asks. */
async function abortNow() {
  say('');
  try {
    const r = await api('POST', '/api/cell/stop', {});
    say(r.campaign === null
      ? 'Nothing was running: no device is moving.'
      : 'Aborted campaign #' + r.campaign + ': robot ' + (r.robot || 'not told') + ', stage ' + (r.stage || 'not told') + '.');
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
  const terms = $('create-nongeometric').value;
  if (terms) body.nongeometric = terms === 'none' ? [] : terms.split(',');
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
  headers['Last-Event-ID'] = String(f.id === ui.selected ? ui.seenSeq : 0);
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
  const text = data.join('\n');
  let d = text;
  try { d = JSON.parse(text); } catch (_) { /* shown as text */ }
  onEvent(id, Number.isFinite(seq) ? seq : null, kind, d);
  refresh();
}

/** The stored journal of campaign `id` (what happened before this page looked). */
async function readHistory(id) {
  let list;
  try { list = await api('GET', '/api/campaigns/' + id + '/events'); } catch (e) { say('events: ' + e.message); return; }
  if (id !== ui.selected) return;
  ui.historyFor = id;
  for (const e of Array.isArray(list) ? list : []) onEvent(id, e.seq, e.kind, e.event);
}

/** One journalled event of campaign `id` (live or stored): the log, the drift table, the plot. */
function onEvent(id, seq, kind, d) {
  if (id !== ui.selected) return;
  if (seq !== null) {
    if (seq <= ui.seenSeq) return;
    ui.seenSeq = seq;
  }
  logEvent(seq, kind, summary(kind, d));
  if (typeof d !== 'object' || d === null) return;
  if (kind === 'measured') {
    ui.measured.push({ done: d.done, total: d.total, pose: d.pose, dev: d.deviation_mm });
    renderDeviation();
  } else if (kind === 'drift') {
    const last = ui.measured[ui.measured.length - 1];
    ui.drifts.push({ after: last ? last.done : 0, drift_mm: d.drift_mm, max_mm: d.max_mm });
    renderDrift();
  }
}

function summary(kind, d) {
  if (typeof d !== 'object' || d === null) return String(d);
  switch (kind) {
    case 'state': return (d.state && (d.state.state || d.state)) + (d.state && d.state.reason ? ': ' + d.state.reason : '');
    case 'measured': return 'pose ' + d.pose + ' measured (' + d.done + ' / ' + d.total + ')'
      + (typeof d.deviation_mm === 'number' ? ', ' + human.mm(d.deviation_mm) + ' mm from the nominal model' : '');
    case 'prompt': return 'question ' + d.seq + ': ' + d.text;
    case 'note': return d.text;
    case 'ident_stopped': return 'identification poses stopped after ' + d.after_poses + ', ' + d.skipped
      + ' skipped (' + d.reason + '): predicted verification error ' + human.mm(d.predicted_mm) + ' mm';
    case 'devices': return ['tracker', 'robot', 'stage'].map((k) => k + ' ' + (d[k] || 'unknown')).join('; ');
    case 'fault': return d.device + ' ' + d.kind + ': ' + d.message + ' → ' + d.action;
    case 'drift': return 'drift ' + human.mm(d.drift_mm) + ' mm (max ' + human.mm(d.max_mm) + ' mm)';
    case 'result': return 'result: quality ' + ((d.json && d.json.quality) || '—');
    default: {
      const text = JSON.stringify(d);
      return text.length > 200 ? text.slice(0, 200) + '…' : text;
    }
  }
}

function logEvent(seq, kind, text) {
  const li = document.createElement('li');
  if (seq !== null) {
    const n = document.createElement('span');
    n.className = 'seq';
    n.textContent = '#' + seq;
    li.append(n, ' ');
  }
  li.append(kind + ': ' + text);
  const log = $('event-log');
  log.prepend(li);
  while (log.children.length > 500) log.lastElementChild.remove();
}

// ---- drift checks and the deviation plot ------------------------------------------------

function renderDrift() {
  const body = $('drift-checks').tBodies[0];
  body.replaceChildren();
  ui.drifts.forEach((c, i) => {
    const tr = document.createElement('tr');
    const over = !(c.drift_mm <= c.max_mm);
    cell(tr, String(i + 1));
    cell(tr, i === 0 ? 'reference' : String(c.after));
    cell(tr, human.mm(c.drift_mm));
    cell(tr, human.mm(c.max_mm));
    cell(tr, over ? 'OVER' : 'ok');
    if (over) tr.lastChild.className = 'over';
    body.prepend(tr);
  });
  $('drift-note').textContent = ui.drifts.length ? '' : 'none yet';
}

const SVG = 'http://www.w3.org/2000/svg';

function svg(parent, tag, attrs, text) {
  const el = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  if (text !== undefined) el.textContent = text;
  parent.appendChild(el);
  return el;
}

/** The smallest of 1, 2, 5 × 10^k at least `x`: the plot's top. */
function niceCeil(x) {
  const p = Math.pow(10, Math.floor(Math.log10(x)));
  for (const m of [1, 2, 5, 10]) if (m * p >= x) return m * p;
  return 10 * p;
}

/** Each measured pose's deviation from the nominal model (mm) against the measuring order. */
function renderDeviation() {
  const plot = $('deviation-plot');
  plot.replaceChildren();
  const W = 900; const H = 240; const L = 76; const R = 14; const T = 12; const B = 36;
  const pts = ui.measured.filter((p) => typeof p.dev === 'number' && Number.isFinite(p.dev));
  const total = Math.max(1, ui.view ? ui.view.poses_total : 0, ...ui.measured.map((p) => p.total || 0));
  const top = niceCeil(Math.max(0.1, ...pts.map((p) => p.dev)));
  const x = (done) => L + ((W - L - R) * (done - 1)) / Math.max(1, total - 1);
  const y = (mm) => T + (H - T - B) * (1 - mm / top);
  for (const f of [0, 0.5, 1]) {
    svg(plot, 'line', { class: 'grid', x1: L, x2: W - R, y1: y(top * f), y2: y(top * f) });
    svg(plot, 'text', { x: L - 6, y: y(top * f) + 4, 'text-anchor': 'end' }, human.mm(top * f) + ' mm');
  }
  svg(plot, 'line', { class: 'axis', x1: L, x2: L, y1: T, y2: H - B });
  svg(plot, 'line', { class: 'axis', x1: L, x2: W - R, y1: H - B, y2: H - B });
  svg(plot, 'text', { x: L, y: H - B + 16, 'text-anchor': 'middle' }, '1');
  svg(plot, 'text', { x: W - R, y: H - B + 16, 'text-anchor': 'end' }, String(total));
  svg(plot, 'text', { x: (L + W - R) / 2, y: H - 4, 'text-anchor': 'middle' }, 'pose (measuring order)');
  if (pts.length > 1) {
    svg(plot, 'polyline', { class: 'line', points: pts.map((p) => x(p.done) + ',' + y(p.dev)).join(' ') });
  }
  pts.forEach((p, i) => {
    const dot = svg(plot, 'circle', { class: i === pts.length - 1 ? 'dot last' : 'dot', cx: x(p.done), cy: y(p.dev), r: 3.5 });
    svg(dot, 'title', {}, 'pose ' + p.pose + ': ' + human.mm(p.dev) + ' mm');
  });
  plot.dataset.points = pts.length;
  const note = $('deviation-summary');
  if (!ui.measured.length) {
    note.textContent = 'no pose measured yet';
  } else if (!pts.length) {
    note.textContent = 'no prediction to compare with: the base is not registered (setup.base_registration = false)';
  } else {
    const devs = pts.map((p) => p.dev);
    const mean = devs.reduce((a, b) => a + b, 0) / devs.length;
    note.textContent = pts.length + ' poses · last ' + human.mm(devs[devs.length - 1]) + ' mm · mean '
      + human.mm(mean) + ' mm · max ' + human.mm(Math.max(...devs)) + ' mm';
  }
}

// ---- device status ---------------------------------------------------------------------

/** Read `GET /api/devices`; a daemon without that route shows every device as unknown. */
async function pollDevices() {
  if (!ui.me) return;
  let d = null;
  let note = '';
  try {
    d = await api('GET', '/api/devices');
  } catch (e) {
    note = e.status === 404 ? 'this daemon does not report device status' : 'device status: ' + e.message;
  }
  renderDevices(d, note);
}

/** What to say of a device's connection, and its style: red only for a connection fault. */
function connectionText(dev) {
  const said = {
    connected: ['yes', 'yes'],
    fault: ['NO — connection fault', 'no'],
    not_connected_yet: ['not connected yet', 'idle'],
    closed: ['closed (no campaign running)', 'idle'],
    no_connection: ['no connection (manual micrometer)', 'idle'],
  };
  if (dev && Object.hasOwn(said, dev.connection)) return said[dev.connection];
  // a daemon without `connection`: only `connected`
  const c = dev ? dev.connected : null;
  return c === true ? ['yes', 'yes'] : c === false ? ['NO', 'no'] : ['unknown', 'idle'];
}

function renderDevices(d, note) {
  for (const name of ['tracker', 'robot', 'stage']) {
    const dev = d && d[name] ? d[name] : null;
    const cells = $('device-' + name).cells;
    cells[1].textContent = dev ? String(dev.kind) + (dev.simulated ? ' (simulated)' : '') : '';
    cells[2].textContent = dev && dev.address != null ? String(dev.address) : '';
    const [text, cls] = connectionText(dev);
    cells[3].textContent = text;
    cells[3].className = cls;
    const f = dev ? dev.last_fault : null;
    cells[4].textContent = !dev ? '' : !f ? 'none'
      : f.kind + ': ' + f.message + (f.at_ms ? ' (' + human.localTime(f.at_ms) + ')' : '');
    cells[5].textContent = dev && typeof dev.identity === 'string' ? dev.identity : '';
  }
  $('device-note').textContent = note;
}

// ---- result ----------------------------------------------------------------------------

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
  const bases = {
    setup_registration: "the setup's base registration (as the live deviation above)",
    fitted_to_poses: 'a base fitted to the identification poses',
    robot_model: "the robot model's own base",
  };
  $('result-before-base').textContent = 'before = the nominal model with the setup\'s tool and '
    + (Object.hasOwn(bases, r.before_base) ? bases[r.before_base] : 'a base the result does not name');
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
      cell(tr, human.mm(m.before[k]));
      cell(tr, human.mm(m.after[k]));
      if (set === 'verify' && k === 'position_mean_mm') tr.lastChild.id = 'result-verify-after';
    }
    mbody.appendChild(tr);
  }
  const pbody = $('result-parameters').tBodies[0];
  pbody.replaceChildren();
  for (const p of Array.isArray(r.parameters) ? r.parameters : []) {
    const tr = document.createElement('tr');
    // lengths in mm; angles: the nominal in degrees, its error and σ in mrad
    const angle = p.unit === 'rad';
    cell(tr, p.name);
    cell(tr, angle ? human.deg(p.nominal) + '°' : human.mm(p.nominal) + ' mm');
    const small = angle ? human.mrad : human.mm;
    cell(tr, human.withSigma(small(p.error), p.std == null ? null : small(p.std)) + (angle ? ' mrad' : ' mm'));
    cell(tr, p.status === 'setup_relative' ? 'yes, relative to the setup' : p.identified ? 'yes' : 'no');
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

// ---- hand-over: the calibration's files ----------------------------------------------

/** The files of a campaign the page hands over: button, route, file name, what it needs. */
const DOWNLOADS = [
  { id: 'download-report', route: '/report', file: 'report.html', needs: 'result' },
  { id: 'download-model', route: '/model', file: 'model.toml', needs: 'result' },
  { id: 'download-csv', route: '/measurements?format=csv', file: 'measurements.csv', needs: 'measured' },
  { id: 'download-result', route: '/result', file: 'result.json', needs: 'result' },
  { id: 'download-events', route: '/events', file: 'events.json', needs: 'campaign' },
];

/** Why campaign view `v` does not have what `needs` names yet; null when it has. */
function missing(v, needs) {
  if (!v) return 'no campaign selected';
  if (needs === 'result' && !v.has_result) {
    return 'campaign #' + v.id + ' has no result yet: it is identified after its last pose';
  }
  if (needs === 'measured' && !v.poses_done) return 'campaign #' + v.id + ' has no measured pose yet';
  return null;
}

/** Each download enabled once the selected campaign has its file, else disabled with the reason. */
function renderDownloads(v) {
  const reasons = new Set();
  for (const d of DOWNLOADS) {
    const why = missing(v, d.needs);
    const b = $(d.id);
    b.disabled = why !== null;
    b.title = why === null ? 'Save ' + fileName(v.id, d) : why;
    if (why !== null) reasons.add(why);
  }
  $('handover-note').textContent = [...reasons].join(' · ');
}

function fileName(id, d) { return 'campaign-' + id + '-' + d.file; }

/** Save a campaign's file exactly as the API sends it (a plain link could not send the bearer
 *  header): fetch with the token, then a Blob download named `campaign-<id>-<file>`. */
async function download(d) {
  const id = ui.selected;
  if (id === null) return;
  say('');
  try {
    const r = await call('GET', '/api/campaigns/' + id + d.route);
    const url = URL.createObjectURL(await r.blob());
    const a = document.createElement('a');
    a.href = url;
    a.download = fileName(id, d);
    document.body.appendChild(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  } catch (e) {
    say(d.file + ': ' + e.message);
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
  $('prompt-clear').addEventListener('click', confirmClear);
  $('cmd-arm').addEventListener('click', () => { $('arm-dialog').showModal(); $('arm-cancel').focus(); });
  $('arm-confirm').addEventListener('click', () => { $('arm-dialog').close(); command('arm'); });
  $('arm-cancel').addEventListener('click', () => $('arm-dialog').close());
  $('abort-confirm').addEventListener('click', () => { $('abort-dialog').close(); abortNow(); });
  $('abort-cancel').addEventListener('click', () => { $('abort-dialog').close(); if (!$('prompt-panel').hidden) $('prompt-value').focus(); });
  for (const name of ['disarm', 'start', 'pause', 'resume']) {
    $('cmd-' + name).addEventListener('click', () => command(name));
  }
  for (const d of DOWNLOADS) $(d.id).addEventListener('click', () => download(d));
  document.addEventListener('keydown', (ev) => {
    if (ev.key === 'Escape' && !$('prompt-panel').hidden && !$('abort-dialog').open) {
      ev.preventDefault();
      askAbort();
    }
  });
  const sound = $('sound-toggle');
  sound.checked = localStorage.getItem(SOUND_KEY) === '1';
  sound.addEventListener('change', () => {
    localStorage.setItem(SOUND_KEY, sound.checked ? '1' : '0');
    if (sound.checked && !ui.audio) {
      try { ui.audio = new AudioContext(); } catch (_) { /* no audio: the visual cue stands */ }
    }
  });
  setInterval(refresh, 1000);
  setInterval(pollDevices, 3000);
}

wire();
const stored = takeToken();
if (stored) signIn(stored); else signOut('');
