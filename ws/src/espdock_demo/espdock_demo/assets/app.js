'use strict';
// Live state over server-sent events; the settings form posted with fetch.
const $ = (id) => document.getElementById(id);
const form = $('settings');
const sizeNames = JSON.parse($('size-names').textContent);
let online = null;

function showConfig(config) {
  $('config').textContent = JSON.stringify(config, null, 1);
  const unknown = $('config-unknown');
  if (unknown) unknown.remove();
}

function applyConfig(config) {
  for (const [name, value] of Object.entries(config)) {
    const el = form.querySelector(`[data-setting="${CSS.escape(name)}"]`);
    if (!el) continue;
    if (el.type === 'checkbox') el.checked = Boolean(value);
    else el.value = String(value);
    const out = document.getElementById('out-' + name);
    if (out) out.textContent = String(value);
  }
  showConfig(config);
}

// What the user set and has not applied yet stays in the form: the live state then only
// updates the read-out. (Assigning .value or .checked fires neither event.)
for (const kind of ['input', 'change']) {
  form.addEventListener(kind, () => { form.dataset.edited = '1'; });
}

function restartStream() {
  $('stream').src = '/stream.mjpg?t=' + Date.now();
}

function render(state) {
  const cam = state.camera;
  $('nocam').hidden = cam.online;
  $('camera-info').textContent = cam.online
    ? `${cam.width}x${cam.height} at ${cam.fps.toFixed(1)} fps` : 'no camera';
  if (online === false && cam.online) restartStream();
  online = cam.online;
  const cut = state.qr && state.qr.length > state.qr.text.length ? ` … (${state.qr.length} characters)` : '';
  $('qr').textContent = state.qr ? state.qr.text + cut : '(none yet)';
  if (state.led) {
    $('swatch').style.backgroundColor = state.led.hex;
    $('led-hex').textContent = state.led.hex;
  }
  if (state.config) {
    if (form.dataset.busy || form.dataset.edited) showConfig(state.config);
    else applyConfig(state.config);
  }
  const nodes = Object.entries(state.nodes || {});
  const down = nodes.filter(([, n]) => n.state !== 'ok');
  $('nodes').textContent = nodes.length === 0 ? '(waiting for their diagnostics)'
    : down.length === 0 ? `all ${nodes.length} running`
    : down.map(([name, n]) => name.slice(1) + (n.state === 'stale'
        ? ` down or stuck (silent for ${Math.round(n.silent_s)} s)`
        : n.state === 'missing' ? ` not up after ${Math.round(n.silent_s)} s` : ' not seen yet')).join('; ');
  $('nodes').className = down.length ? 'warn' : '';
}

const events = new EventSource('/events');
events.addEventListener('state', (e) => render(JSON.parse(e.data)));
$('stream').addEventListener('error', () => setTimeout(restartStream, 1000));
// A UI server that stopped cleanly (a restart) ended the stream as a finished picture, which
// fires no error: the events reconnecting to its successor say the stream needs it too.
let eventsLost = false;
events.addEventListener('error', () => { eventsLost = true; });
events.addEventListener('open', () => { if (eventsLost) restartStream(); eventsLost = false; });

for (const slider of form.querySelectorAll('input[type=range]')) {
  slider.addEventListener('input', () => { $('out-' + slider.name).textContent = slider.value; });
}

function describe(config) {
  const size = sizeNames[config.framesize] || config.framesize;
  return `framesize ${size}, quality ${config.quality}, brightness ${config.brightness}, ` +
    `hmirror ${config.hmirror}, vflip ${config.vflip}, colorbar ${config.colorbar}`;
}

form.addEventListener('submit', async (event) => {
  event.preventDefault();
  const result = $('result');
  form.dataset.busy = '1';
  $('apply').disabled = true;
  result.className = '';
  result.textContent = 'Waiting for the camera…';
  try {
    const response = await fetch('/config', {
      method: 'POST', body: new URLSearchParams(new FormData(form)),
      headers: {'Accept': 'application/json'},
    });
    const answer = await response.json();
    result.className = answer.ok ? 'ok' : 'error';
    result.textContent = answer.message + (answer.config ? ' Camera now: ' + describe(answer.config) + '.' : '');
    if (answer.ok) {
      delete form.dataset.edited;
      if (answer.config) applyConfig(answer.config);
    } else if (answer.config) {
      showConfig(answer.config);  // refused: the user's values stay in the form, to be mended
    }
  } catch (err) {
    result.className = 'error';
    result.textContent = 'The UI server did not answer: ' + err;
  } finally {
    delete form.dataset.busy;
    $('apply').disabled = false;
  }
});
