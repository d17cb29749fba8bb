// pulsegate status page. Listens to /api/v1/events (the snapshot once a second) and redraws.
// Every name, unit and message from the gateway goes into the page as text (textContent), never
// as markup: they come from config and profile files. No other host is contacted.
'use strict';
(function () {
  const POLL_MS = 1000;
  const $ = (id) => document.getElementById(id);
  let previous = null; // the last answer, for transactions a second

  function el(tag, className, text) {
    const e = document.createElement(tag);
    if (className) e.className = className;
    if (text !== undefined && text !== null) e.textContent = String(text);
    return e;
  }

  function cell(row, text, className) {
    const td = el('td', className, text);
    row.appendChild(td);
    return td;
  }

  function badge(text, tone) {
    return el('span', 'badge ' + (tone || ''), text);
  }

  function age(ms) {
    if (ms === null || ms === undefined || ms < 0) return '';
    const s = ms / 1000;
    if (s < 1) return 'now';
    if (s < 90) return Math.round(s) + ' s ago';
    if (s < 5400) return Math.round(s / 60) + ' min ago';
    if (s < 172800) return Math.round(s / 3600) + ' h ago';
    return Math.round(s / 86400) + ' d ago';
  }

  function since(now, at) {
    return at === null || at === undefined ? '' : age(now - at);
  }

  function duration(s) {
    if (s < 120) return Math.round(s) + ' s';
    if (s < 7200) return Math.round(s / 60) + ' min';
    if (s < 172800) return (s / 3600).toFixed(1) + ' h';
    return (s / 86400).toFixed(1) + ' d';
  }

  function num(v, digits) {
    if (v === null || v === undefined) return '';
    if (typeof v !== 'number') return String(v);
    if (digits !== undefined) return v.toFixed(digits);
    return Number.isInteger(v) ? v.toLocaleString('en-US').replace(/,/g, '\u202f') : String(v);
  }

  function bytes(n) {
    if (n < 1024) return n + ' B';
    if (n < 1048576) return (n / 1024).toFixed(1) + ' KiB';
    return (n / 1048576).toFixed(1) + ' MiB';
  }

  function clock(ms) {
    return new Date(ms).toLocaleTimeString([], { hour12: false });
  }

  function replace(parent, children) {
    while (parent.firstChild) parent.removeChild(parent.firstChild);
    for (const c of children) parent.appendChild(c);
  }

  function statusTone(status) {
    if (status === 'online') return 'ok';
    if (status === 'unknown') return '';
    return 'bad';
  }

  // --- gateway and outputs ---------------------------------------------------------------
  function renderGateway(s) {
    const g = s.gateway;
    $('gateway-id').textContent = g.id;
    const facts = [
      ['version', g.version],
      ['up for', duration(g.uptime_s) + ' (since ' + new Date(g.started_ms).toLocaleString() + ')'],
      ['config file', g.config_file],
      ['config hash', g.config_hash.slice(0, 12)],
    ];
    const items = [];
    for (const [k, v] of facts) {
      items.push(el('dt', null, k));
      const dd = el('dd', null, v);
      if (k === 'config hash') dd.title = g.config_hash;
      items.push(dd);
    }
    replace($('gateway-facts'), items);
    const rows = s.outputs.map((o) => {
      const tr = el('tr');
      tr.dataset.output = o.name;
      cell(tr, o.name);
      cell(tr, o.format || 'gateway', 'muted');
      cell(tr, o.broker);
      const conn = cell(tr, '');
      if (o.held) conn.appendChild(badge('held: ' + o.held, 'warn'));
      else if (o.connected) conn.appendChild(badge('connected', 'ok'));
      else conn.appendChild(badge('disconnected' + (o.down_s ? ' ' + duration(o.down_s) : ''), 'bad'));
      let spool = o.spooling ? num(o.spool_messages) + ' waiting, ' + bytes(o.spool_bytes) : 'empty';
      if (o.spool_limit_bytes) spool += ' (' + (100 * o.spool_bytes / o.spool_limit_bytes).toFixed(1) + '% of ' + bytes(o.spool_limit_bytes) + ')';
      cell(tr, spool, o.spooling ? '' : 'muted');
      const err = o.problem || o.last_error;
      cell(tr, err ? err + ' (' + since(s.now_ms, o.last_error_ms) + ')' : 'none', err ? 'wrap' : 'muted');
      return tr;
    });
    replace(document.querySelector('#outputs tbody'), rows);
  }

  // --- buses -------------------------------------------------------------------------------
  function txPerS(s, b) {
    if (previous) {
      const p = previous.buses.find((x) => x.name === b.name);
      const dt = (s.now_ms - previous.now_ms) / 1000;
      if (p && dt > 0.2 && b.transactions >= p.transactions) return (b.transactions - p.transactions) / dt;
    }
    return b.stats ? b.stats.transactions_per_s : null;
  }

  function renderBuses(s) {
    const rows = s.buses.map((b) => {
      const tr = el('tr');
      tr.dataset.bus = b.name;
      cell(tr, b.name);
      cell(tr, b.link, 'muted');
      const line = cell(tr, '');
      line.appendChild(b.problem ? badge(b.problem, 'bad') : b.up ? badge('up', 'ok') : badge('down', 'bad'));
      const st = b.stats || {};
      cell(tr, num(txPerS(s, b), 1), 'num');
      cell(tr, b.stats ? (100 * st.utilisation).toFixed(0) + '%' : '', 'num');
      cell(tr, num(st.timeouts), 'num');
      cell(tr, num(st.garbled), 'num');
      cell(tr, num(st.stale_dropped), 'num');
      cell(tr, num(b.reconnects), 'num');
      cell(tr, num(b.line_faults), 'num');
      return tr;
    });
    replace($('bus-rows'), rows);
  }

  // --- devices and channels ----------------------------------------------------------------
  function fact(parent, label, value) {
    if (value === '' || value === null || value === undefined) return;
    const span = el('span', null, label + ' ');
    span.appendChild(el('b', null, value));
    parent.appendChild(span);
  }

  function ms(v) {
    return v === null || v === undefined ? '' : v.toFixed(v < 10 ? 1 : 0) + ' ms';
  }

  function renderDevice(s, d) {
    const card = el('article', 'device' + (d.status === 'offline' ? ' offline' : d.status !== 'online' && d.status !== 'unknown' ? ' problem' : ''));
    card.dataset.device = d.name;
    const head = el('div', 'device-head');
    head.appendChild(el('h3', null, d.name));
    const st = badge(d.status, statusTone(d.status));
    st.classList.add('status');
    head.appendChild(st);
    head.appendChild(el('span', 'muted', d.model + ' · bus ' + d.bus + ' · ' + d.address));
    card.appendChild(head);
    const facts = el('div', 'device-facts');
    fact(facts, 'last answer', since(s.now_ms, d.last_answer_ms) || 'never');
    fact(facts, 'latency', ms(d.latency_ms));
    if (d.latency_p50_ms !== null) fact(facts, 'p50/p99', ms(d.latency_p50_ms) + ' / ' + ms(d.latency_p99_ms));
    fact(facts, 'poll', num(d.poll_ms) + ' ms');
    fact(facts, 'timeouts', num(d.timeouts));
    fact(facts, 'garbled', num(d.garbled));
    fact(facts, 'exceptions', num(d.exceptions));
    if (d.missed) fact(facts, 'missed polls', num(d.missed));
    if (d.request) fact(facts, 'requests', d.request.requests_per_poll + ' a poll, ≤ ' + d.request.limit + ' registers');
    card.appendChild(facts);
    if (d.last_error) card.appendChild(el('p', 'error', 'last error: ' + d.last_error));
    if (d.channels.length) card.appendChild(channelTable(s, d));
    else card.appendChild(el('p', 'muted', 'no reading yet'));
    return card;
  }

  function channelTable(s, d) {
    const wrap = el('div', 'scroll');
    const table = el('table');
    const head = el('tr');
    for (const h of ['channel', 'count', 'total', 'rate', 'updated', 'last 15 min', 'interval']) {
      head.appendChild(el('th', h === 'count' || h === 'total' || h === 'rate' ? 'num' : null, h));
    }
    const thead = el('thead');
    thead.appendChild(head);
    table.appendChild(thead);
    const body = el('tbody');
    for (const c of d.channels) body.appendChild(channelRow(s, d, c));
    table.appendChild(body);
    wrap.appendChild(table);
    return wrap;
  }

  function channelRow(s, d, c) {
    const tr = el('tr');
    tr.dataset.channel = d.name + '/' + c.name;
    const name = cell(tr, c.name);
    if (c.event) name.appendChild(el('span', 'muted', ' ' + c.event));
    const gauge = c.kind === 'gauge';
    cell(tr, gauge ? '' : num(c.count), 'num count');
    const total = cell(tr, c.value !== null ? c.value : num(c.total), 'num total');
    if (c.unit !== null) total.appendChild(el('span', 'unit muted', ' ' + c.unit));
    let rate = '';
    if (c.rate !== null) rate = num(c.rate);
    else if (c.rate_hz !== null) rate = c.rate_hz.toFixed(c.rate_hz < 10 ? 2 : 1);
    const r = cell(tr, rate, 'num rate');
    r.appendChild(el('span', 'muted', c.rate !== null ? ' ' + (c.rate_unit || '') : rate ? ' /s' : ''));
    cell(tr, since(s.now_ms, c.at_ms), 'age muted');
    const chart = el('canvas', 'chart');
    chart.width = 120;
    chart.height = 28;
    chart.setAttribute('aria-label', c.name + ': rate over the last 15 minutes');
    draw(chart, c.history.rates);
    if (gauge) cell(tr, '');
    else cell(tr, '').appendChild(chart);
    const iv = cell(tr, '', 'interval');
    for (const i of c.intervals) {
      const left = Math.max(0, Math.round((i.end_ms - s.now_ms) / 60000));
      iv.appendChild(el('div', null, i.period + ': ' + num(i.delta) + ' so far, ' + left + ' min left'));
    }
    return tr;
  }

  // A bar per bucket; the zero line in the middle when the rate goes both ways (an encoder).
  function draw(canvas, rates) {
    const g = canvas.getContext('2d');
    if (!g) return;
    const w = canvas.width, h = canvas.height;
    g.clearRect(0, 0, w, h);
    const known = rates.filter((r) => r !== null);
    if (!known.length) return;
    const hi = Math.max(0, ...known), lo = Math.min(0, ...known);
    const span = hi - lo || 1;
    const zero = h - 1 - ((0 - lo) / span) * (h - 2);
    const bw = w / rates.length;
    g.fillStyle = getComputedStyle(document.documentElement).getPropertyValue('--chart') || '#2563eb';
    rates.forEach((r, i) => {
      if (r === null) return;
      const y = h - 1 - ((r - lo) / span) * (h - 2);
      g.fillRect(i * bw + 0.5, Math.min(y, zero), Math.max(1, bw - 1), Math.max(1, Math.abs(zero - y)));
    });
    g.fillStyle = '#9ca3af';
    g.fillRect(0, Math.round(zero), w, 1);
  }

  // --- events and scan ---------------------------------------------------------------------
  function renderEvents(s) {
    const items = s.events.map((e) => {
      const li = el('li');
      li.appendChild(el('span', 'muted', clock(e.at_ms)));
      li.appendChild(el('span', 'kind muted', e.kind));
      const where = [e.device, e.channel].filter((x) => x).join('/');
      li.appendChild(el('span', 'what', (where ? where + ': ' : '') + e.text));
      return li;
    });
    if (!items.length) items.push(el('li', 'muted', 'nothing yet'));
    replace($('event-list'), items);
  }

  function renderScan(s) {
    const section = $('scan');
    const scan = s.scan;
    section.hidden = !scan;
    if (!scan) return;
    const all = scan.asked + scan.pending;
    $('scan-summary').textContent = 'bus ' + scan.bus + (scan.id ? ' (' + scan.id + ')' : '') + ': ' +
      (scan.running ? 'running, ' : 'done, ') + scan.asked + ' of ' + all + ' units asked in ' +
      (scan.elapsed_ms / 1000).toFixed(1) + ' s, ' + scan.found.length + ' found';
    const bar = $('scan-progress');
    bar.max = Math.max(1, all);
    bar.value = scan.asked;
    replace($('scan-found'), scan.found.map((f) => el('li', null,
      'unit ' + f.unit + (f.baud ? ' at ' + f.baud + ' baud' : '') + ': ' + (f.model || 'unknown model') +
      (f.channels.length ? ' (' + f.channels.join(', ') + ')' : '') + (f.note ? ' — ' + f.note : ''))));
  }

  // --- the loop ----------------------------------------------------------------------------
  function render(s) {
    renderGateway(s);
    renderScan(s);
    renderBuses(s);
    replace($('device-list'), s.devices.map((d) => renderDevice(s, d)));
    renderEvents(s);
    previous = s;
  }

  function link(ok, text) {
    const b = $('link');
    b.textContent = text;
    b.className = 'badge ' + (ok ? 'ok' : 'bad');
  }

  // The gateway pushes the snapshot once a second (server-sent events): one open stream, no
  // request a second. Where the stream cannot be had (refused, or the browser has none), the
  // page asks /api/v1/status once a second instead.
  const QUIET_MS = 5000; // no snapshot for this long: the gateway is not answering
  let heard = 0;

  function show(s) {
    heard = Date.now();
    render(s);
    link(true, 'live');
  }

  async function poll() {
    try {
      const r = await fetch('api/v1/status', { cache: 'no-store', credentials: 'same-origin' });
      if (r.status === 401) {
        window.location.assign('login');
        return;
      }
      if (!r.ok) throw new Error('HTTP ' + r.status);
      show(await r.json());
    } catch (e) {
      link(false, 'gateway not answering');
    }
    setTimeout(poll, POLL_MS);
  }

  function listen() {
    const events = new EventSource('api/v1/events');
    events.onmessage = (e) => show(JSON.parse(e.data));
    events.onerror = () => {
      link(false, 'gateway not answering');
      // CLOSED: refused (a 401 or another answer than a stream); the poll finds out which.
      if (events.readyState === EventSource.CLOSED) poll();
    };
    setInterval(() => {
      if (Date.now() - heard > QUIET_MS) link(false, 'gateway not answering');
    }, POLL_MS);
  }

  if (typeof EventSource === 'function') listen();
  else poll();
})();
