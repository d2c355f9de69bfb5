// navsvc map view: the road graph of the served map, the live sessions, and for the chosen
// session its raw GPS fixes, fused track, matched positions, ambiguity candidates, GPS usage
// and outages; live over the viewer WebSocket, or a whole file under `navsvc view`.
// Everything comes from the navsvc server that served this page: no tiles, no CDN.
"use strict";
(() => {
  const OUTAGE_GAP_S = 3.0;  // no GPS fix for longer than this: the track is in an outage
  const POLL_MS = 2000;  // the session list is refreshed this often
  const $ = (id) => document.getElementById(id);
  const esc = (text) => String(text).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
  const fmt = (v, digits, unit) => (v === null || v === undefined) ? "–"
    : `${Number(v).toFixed(digits)}${unit ? " " + unit : ""}`;

  const app = {
    config: null, key: sessionStorage.getItem("navsvc-api-key") || "", selected: null,
    sessions: [], ws: null, wsFailures: 0, roadIndex: new Map(), roadsLoaded: false,
    replay: null, replayCursor: 0, replayTimer: null, followed: false, pollTimer: null,
  };

  // --- the map and its layers -----------------------------------------------------------
  const map = L.map("map", {zoomSnap: 0.25, minZoom: 3, maxZoom: 20});
  map.attributionControl.setPrefix("Leaflet");
  map.attributionControl.addAttribution("roads © OpenStreetMap contributors");
  const roadRenderer = L.canvas({padding: 0.3});
  const fixRenderer = L.canvas({padding: 0.3});
  const layers = {
    roads: L.layerGroup().addTo(map),
    truth: L.polyline([], {color: "#111", weight: 2, dashArray: "2 5", interactive: false}),
    fixes: L.layerGroup().addTo(map),
    fused: L.polyline([], {color: "#1f77b4", weight: 3, opacity: 0.85}).addTo(map),
    outages: L.layerGroup().addTo(map),
    matched: L.polyline([], {color: "#2ca02c", weight: 3, opacity: 0.9}).addTo(map),
    candidates: L.layerGroup().addTo(map),
    sigma: L.circle([0, 0], {radius: 1, color: "#1f77b4", weight: 1, fillOpacity: 0.08,
                             interactive: false}),
    current: L.circleMarker([0, 0], {radius: 8, color: "#fff", weight: 2, fillColor: "#2ca02c",
                                     fillOpacity: 1}),
  };
  const ROAD_WEIGHT = {motorway: 4, trunk: 4, primary: 3.5, secondary: 3, tertiary: 2.5};

  function roadKey(u, v, key) { return `${u}-${v}-${key}`; }

  function drawRoads(geojson) {
    layers.roads.clearLayers();
    app.roadIndex.clear();
    const layer = L.geoJSON(geojson, {
      renderer: roadRenderer,
      style: (f) => ({color: f.properties.tunnel ? "#c3c8ce" : "#9aa3ad",
                      weight: ROAD_WEIGHT[f.properties.highway] || 2,
                      dashArray: f.properties.tunnel ? "4 4" : null, opacity: 1}),
      onEachFeature: (f, l) => {
        const p = f.properties;
        app.roadIndex.set(roadKey(p.u, p.v, p.key), l);
        l.bindTooltip(esc(`${p.name || p.highway} (${p.u}→${p.v}, ${Math.round(p.length_m)} m)`),
                      {sticky: true});
      },
    });
    layer.addTo(layers.roads);
    app.roadsLoaded = true;
  }

  async function loadRoads(bbox) {
    const r = await api(`/v1/maps/${encodeURIComponent(app.config.map)}/edges?bbox=${bbox.join(",")}`);
    if (r.status === 413) {  // a big map: draw the roads of the view once zoomed in
      app.bigMap = true;
      return;
    }
    if (!r.ok) throw new Error(`roads: ${r.status}`);
    drawRoads(await r.json());
  }

  map.on("moveend", () => {
    if (app.bigMap && map.getZoom() >= 15) {
      const b = map.getBounds();
      loadRoads([b.getWest(), b.getSouth(), b.getEast(), b.getNorth()].map((x) => x.toFixed(5)))
        .catch(console.error);
    }
  });

  // --- one session's track --------------------------------------------------------------
  class Track {
    constructor() { this.reset(); }

    reset() {
      this.fixes = 0; this.positions = 0; this.lastFixT = null; this.lastT = null;
      this.fixTimes = new Set(); this.outages = []; this.open = null; this.gps = new Map();
      this.latest = null; this.prevFused = null;
      for (const name of ["fixes", "outages", "candidates"]) layers[name].clearLayers();
      for (const name of ["fused", "matched", "truth"]) layers[name].setLatLngs([]);
      layers.current.remove(); layers.sigma.remove();
    }

    addFix(f) {
      if (f.lat === null || f.lon === null) return;
      this.fixes += 1;
      this.fixTimes.add(f.t);
      L.circleMarker([f.lat, f.lon], {renderer: fixRenderer, radius: 3, color: "#d62728",
                                      weight: 1, fillOpacity: 0.6})
        .bindTooltip(`fix t=${f.t}${f.accuracy_m ? `, ±${f.accuracy_m} m` : ""}` +
                     `${f.hdop ? `, HDOP ${f.hdop}` : ""}`)
        .addTo(layers.fixes);
      if (this.open !== null) {  // the outage ends with this fix
        this.open.end = f.t;
        this.open = null;
      }
      this.lastFixT = this.lastFixT === null ? f.t : Math.max(this.lastFixT, f.t);
    }

    addPosition(p) {
      this.positions += 1;
      this.lastT = p.t;
      this.latest = p;
      if (p.fused_lat !== null && p.fused_lon !== null) {
        const fused = [p.fused_lat, p.fused_lon];
        layers.fused.addLatLng(fused);
        this.trackOutage(p, fused);
        this.prevFused = fused;
      }
      if (p.lat !== null && p.lon !== null) layers.matched.addLatLng([p.lat, p.lon]);
      if (p.gps && this.fixTimes.has(p.t)) {  // the position of a fix: how it was used
        const label = p.gps.used ? (p.gps.weight < 0.999 ? `used, weight < 1: ${p.gps.reason}`
                                                          : `used: ${p.gps.reason}`)
                                 : `not used: ${p.gps.reason}`;
        this.gps.set(label, (this.gps.get(label) || 0) + 1);
      }
    }

    trackOutage(p, fused) {
      const inOutage = this.lastFixT !== null && p.t - this.lastFixT > OUTAGE_GAP_S;
      if (!inOutage) return;
      if (this.open === null) {
        const line = L.polyline(this.prevFused ? [this.prevFused] : [],
                                {color: "#9467bd", weight: 4, dashArray: "6 6"})
          .addTo(layers.outages);
        const outage = {start: this.lastFixT, end: null, line};
        line.bindTooltip(() => outageText(outage));
        this.open = outage;
        this.outages.push(outage);
      }
      this.open.line.addLatLng(fused);
      this.open.last = p.t;
    }

    addTruth(records) {
      layers.truth.setLatLngs(records.map((r) => [r.lat, r.lon])).addTo(map);
    }
  }
  const track = new Track();

  function outageText(o) {
    const end = o.end === null ? (track.lastT ?? o.start) : o.end;
    return `GPS outage from t=${fmt(o.start, 1)} s, ${fmt(end - o.start, 1)} s` +
           (o.end === null ? " (ongoing)" : "");
  }

  // --- the details panel ----------------------------------------------------------------
  let panelQueued = false;
  function updatePanel() {
    if (panelQueued) return;
    panelQueued = true;
    requestAnimationFrame(() => { panelQueued = false; renderPanel(); });
  }

  function renderPanel() {
    const p = track.latest;
    $("details").hidden = app.selected === null && app.replay === null;
    $("d-counts").textContent = `${track.fixes} fixes, ${track.positions} positions drawn`;
    renderOutages();
    renderGpsCounts();
    if (!p) return;
    $("d-t").textContent = fmt(p.t, 2, "s");
    $("d-state").textContent = p.state;
    $("d-state").className = `state ${p.state}`;
    $("d-speed").textContent = p.speed_mps === null ? "–"
      : `${fmt(p.speed_mps, 1, "m/s")} (${fmt(p.speed_mps * 3.6, 0, "km/h")})`;
    $("d-heading").textContent = fmt(p.heading_deg, 0, "°");
    $("d-sigma").textContent = fmt(p.position_sigma_m, 1, "m");
    $("d-road").textContent = p.edge ? `${p.edge.name || "(unnamed)"} ${p.edge.u}→${p.edge.v}` : "–";
    $("d-dist").textContent = fmt(p.distance_to_road_m, 1, "m");
    $("d-next").textContent = p.next_node === null ? "–"
      : `${p.next_node} in ${fmt(p.distance_to_next_node_m, 0, "m")}`;
    const gpsAge = track.lastFixT === null ? null : p.t - track.lastFixT;
    $("d-gps").textContent = !p.gps ? "no fix yet"
      : `last fix ${p.gps.used ? "used" : "not used"} (${p.gps.reason}` +
        `${p.gps.nis !== undefined && p.gps.nis !== null ? `, NIS ${p.gps.nis}` : ""})` +
        (gpsAge !== null && gpsAge > OUTAGE_GAP_S ? `; no fix for ${fmt(gpsAge, 0, "s")}` : "");
    renderCandidates(p);
    placeCurrent(p);
  }

  function renderGpsCounts() {
    const body = $("d-gps-counts").tBodies[0];
    body.replaceChildren(...[...track.gps.entries()].sort((a, b) => b[1] - a[1]).map(([k, n]) => {
      const tr = document.createElement("tr");
      tr.innerHTML = "<td></td><td class=n></td>";
      tr.cells[0].textContent = k; tr.cells[1].textContent = n;
      return tr;
    }));
  }

  function renderOutages() {
    const list = $("d-outages");
    if (!track.outages.length) {
      list.innerHTML = "<li class=hint>none</li>";
      return;
    }
    list.replaceChildren(...track.outages.map((o) => {
      const li = document.createElement("li");
      li.textContent = outageText(o);
      li.onclick = () => map.fitBounds(o.line.getBounds(), {maxZoom: 18, padding: [40, 40]});
      return li;
    }));
  }

  function renderCandidates(p) {
    layers.candidates.clearLayers();
    const ambiguous = p.state === "ambiguous" && p.candidates && p.candidates.length > 0;
    $("d-cands-box").hidden = !ambiguous;
    if (!ambiguous) return;
    const rows = [];
    for (const c of p.candidates) {
      const road = app.roadIndex.get(roadKey(c.edge.u, c.edge.v, c.edge.key));
      const label = `${c.edge.name || "(unnamed)"} ${c.edge.u}→${c.edge.v}`;
      if (road) {
        L.polyline(road.getLatLngs(), {color: "#ff7f0e", weight: 3 + 10 * c.probability,
                                       opacity: 0.75})
          .bindTooltip(esc(`${label}: ${(100 * c.probability).toFixed(0)} %`))
          .addTo(layers.candidates);
      }
      const tr = document.createElement("tr");
      tr.innerHTML = "<td></td><td class=n></td>";
      tr.cells[0].textContent = label;
      tr.cells[1].textContent = `${(100 * c.probability).toFixed(1)} %`;
      rows.push(tr);
    }
    $("d-cands").tBodies[0].replaceChildren(...rows);
  }

  function placeCurrent(p) {
    if (p.lat === null || p.lon === null) return;
    layers.current.setLatLng([p.lat, p.lon]).addTo(map);
    layers.current.bindTooltip(`${p.state}, t=${p.t}`);
    if (p.fused_lat !== null && p.position_sigma_m) {
      layers.sigma.setLatLng([p.fused_lat, p.fused_lon]).setRadius(p.position_sigma_m).addTo(map);
    }
    if (!app.followed) {
      map.setView([p.lat, p.lon], Math.max(map.getZoom(), 17), {animate: false});
      app.followed = true;
    } else if (app.replay === null && !map.getBounds().pad(-0.1).contains([p.lat, p.lon])) {
      map.panTo([p.lat, p.lon]);
    }
  }

  // --- talking to the server ------------------------------------------------------------
  function api(path) {
    return fetch(path, {headers: app.key ? {"X-API-Key": app.key} : {}});
  }

  function setConn(cls, title) {
    $("conn").className = `conn ${cls}`;
    $("conn").title = title;
  }

  function askForKey(message) {
    $("key-form").hidden = false;
    $("sessions-box").hidden = true;
    $("key-error").textContent = message || "";
    $("key-input").focus();
  }

  async function refreshSessions() {
    let r;
    try {
      r = await api("/v1/sessions");
    } catch (e) {
      setConn("down", "the server does not answer");
      return;
    }
    if (r.status === 401) {
      app.key = "";
      sessionStorage.removeItem("navsvc-api-key");
      askForKey(app.sessions.length || $("key-input").value ? "that key was refused" : "");
      return false;
    }
    if (!r.ok) return;
    $("key-form").hidden = true;
    $("sessions-box").hidden = false;
    $("forget-key").hidden = !app.config.keys_required;
    app.sessions = (await r.json()).sessions;
    renderSessions();
    if (app.selected === null && app.sessions.length) {
      const wanted = new URLSearchParams(location.search).get("session");
      const pick = app.sessions.find((s) => s.id === wanted)
        || app.sessions.reduce((a, b) => (b.created_unix > a.created_unix ? b : a));
      select(pick.id);
    }
    return true;
  }

  function renderSessions() {
    $("no-sessions").hidden = app.sessions.length > 0;
    $("sessions").replaceChildren(...app.sessions.map((s) => {
      const li = document.createElement("li");
      li.dataset.id = s.id;
      li.className = s.id === app.selected ? "selected" : "";
      const state = s.position ? s.position.state : "no fix yet";
      li.innerHTML = "<span></span><br><small></small>";
      li.firstChild.textContent = s.vehicle_id;
      li.lastChild.textContent = `${s.id} · ${s.options.sensors || ""} · ${s.packets_accepted} packets · ${state}`;
      li.onclick = () => select(s.id);
      return li;
    }));
  }

  function select(id) {
    if (app.ws) { app.ws.onclose = null; app.ws.close(); }
    app.selected = id;
    app.followed = false;
    track.reset();
    renderSessions();
    const s = app.sessions.find((x) => x.id === id);
    $("d-title").textContent = s ? `${s.vehicle_id} (${id})` : id;
    $("details").hidden = false;
    connect(id);
  }

  function connect(id) {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const query = app.key ? `?api_key=${encodeURIComponent(app.key)}` : "";
    const ws = new WebSocket(`${proto}//${location.host}/v1/sessions/${id}/view${query}`);
    app.ws = ws;
    ws.onopen = () => { app.wsFailures = 0; setConn("live", "live"); };
    ws.onmessage = (event) => onViewerMessage(ws, JSON.parse(event.data));
    ws.onclose = (event) => {
      if (app.ws !== ws) return;
      app.ws = null;
      setConn("down", `viewer closed (${event.code} ${event.reason})`);
      if (event.code === 4401) { askForKey("that key was refused"); return; }
      if (event.code === 4404 || event.reason === "session ended") {
        app.selected = null;
        refreshSessions();
        return;
      }
      app.wsFailures += 1;  // the server went away: try again, a little later each time
      setTimeout(() => { if (app.selected === id) connect(id); },
                 Math.min(10000, 500 * 2 ** app.wsFailures));
    };
  }

  function onViewerMessage(ws, m) {
    if (m.type === "snapshot") {
      track.reset();
      feed(m.fixes, m.positions);
    } else if (m.type === "update") {
      feed(m.fixes, m.positions);
    } else if (m.type === "ended") {
      $("d-title").textContent += " (ended)";
    }
    if (m.dropped) ws.send(JSON.stringify({type: "snapshot"}));  // missed some: start again
  }

  function feed(fixes, positions) {
    // in time order, fixes first at equal times (a position's fix is known when it is drawn)
    const events = fixes.map((f) => [f.t, 0, f]).concat(positions.map((p) => [p.t, 1, p]));
    events.sort((a, b) => a[0] - b[0] || a[1] - b[1]);
    for (const [, type, item] of events) {
      if (type === 0) track.addFix(item); else track.addPosition(item);
    }
    updatePanel();
  }

  // --- replay (navsvc view FILE) -------------------------------------------------------
  async function startReplay() {
    const r = await api("/v1/view/replay");
    const data = await r.json();
    app.replay = data;
    app.replay.events = data.fixes.map((f) => [f.t, 0, f])
      .concat(data.positions.map((p) => [p.t, 1, p]))
      .sort((a, b) => a[0] - b[0] || a[1] - b[1]);
    const times = app.replay.events.map((e) => e[0]);
    const t0 = times.length ? times[0] : 0, t1 = times.length ? times[times.length - 1] : 0;
    $("replay-box").hidden = false;
    $("details").hidden = false;
    $("d-title").textContent = data.source;
    $("replay-source").textContent = `${data.source}: ${data.fixes.length} fixes, ` +
      `${data.positions.length} positions` + (data.truth.length ? `, truth` : "") +
      (data.rejected ? `; ${data.rejected} packets refused` : "");
    const slider = $("replay-time");
    slider.min = t0; slider.max = t1; slider.value = t1;
    slider.oninput = () => { stopPlaying(); replayTo(Number(slider.value)); };
    $("replay-play").onclick = () => (app.replayTimer ? stopPlaying() : play(t0, t1));
    $("replay-all").onclick = () => { stopPlaying(); replayTo(t1); fitTrack(); };
    if (data.truth.length) track.addTruth(data.truth);
    replayTo(t1);
    fitTrack();
    setConn("live", "replaying a file");
  }

  function replayTo(t) {
    const events = app.replay.events;
    if (app.replayCursor > 0 && events[app.replayCursor - 1][0] > t) {  // back in time
      const truth = app.replay.truth;
      track.reset();
      if (truth.length) track.addTruth(truth);
      app.replayCursor = 0;
    }
    const start = app.replayCursor;
    while (app.replayCursor < events.length && events[app.replayCursor][0] <= t) {
      app.replayCursor += 1;
    }
    const slice = events.slice(start, app.replayCursor);
    for (const [, type, item] of slice) {
      if (type === 0) track.addFix(item); else track.addPosition(item);
    }
    $("replay-clock").textContent = `${fmt(t, 1)} s`;
    app.followed = true;  // the replay keeps the view where the user put it
    updatePanel();
  }

  function play(t0, t1) {
    const slider = $("replay-time");
    let t = Number(slider.value) >= t1 ? t0 : Number(slider.value);
    replayTo(t);
    $("replay-play").textContent = "Pause";
    app.replayTimer = setInterval(() => {
      t = Math.min(t1, t + Math.max(1, (t1 - t0) / 300));
      slider.value = t;
      replayTo(t);
      if (t >= t1) stopPlaying();
    }, 50);
  }

  function stopPlaying() {
    if (app.replayTimer) clearInterval(app.replayTimer);
    app.replayTimer = null;
    $("replay-play").textContent = "Play";
  }

  function fitTrack() {
    const b = layers.fused.getBounds();
    if (b.isValid()) map.fitBounds(b, {padding: [30, 30], maxZoom: 18, animate: false});
  }

  // --- start ----------------------------------------------------------------------------
  $("key-form").onsubmit = async (event) => {
    event.preventDefault();
    app.key = $("key-input").value;
    sessionStorage.setItem("navsvc-api-key", app.key);
    if (await refreshSessions()) await start();
  };
  $("forget-key").onclick = () => {
    sessionStorage.removeItem("navsvc-api-key");
    location.reload();
  };
  for (const el of document.querySelectorAll(".origin")) el.textContent = location.origin;

  async function start() {
    if (!app.roadsLoaded) await loadRoads(app.config.bbox);
    if (app.config.replay) {
      await startReplay();
      return;
    }
    if (app.pollTimer === null) app.pollTimer = setInterval(refreshSessions, POLL_MS);
  }

  async function main() {
    app.config = await (await fetch("/v1/view/config")).json();
    $("map-name").textContent = `map ${app.config.map}`;
    const [w, s, e, n] = app.config.bbox;
    map.fitBounds([[s, w], [n, e]]);
    if (app.config.keys_required && !app.key) { askForKey(); return; }
    if (!app.config.replay && !(await refreshSessions())) return;
    await start();
  }

  window.navsvcView = {
    app, map, layers, track,
    // what is drawn, read back from the map's own layers (the browser tests use it)
    drawn: () => ({
      roads: app.roadIndex.size,
      fixes: layers.fixes.getLayers().length,
      fused: layers.fused.getLatLngs().length,
      matched: layers.matched.getLatLngs().length,
      truth: map.hasLayer(layers.truth) ? layers.truth.getLatLngs().length : 0,
      outages: track.outages.length,
      candidates: layers.candidates.getLayers().length,
      current: map.hasLayer(layers.current) ? layers.current.getLatLng() : null,
      lastT: track.lastT, selected: app.selected, replay: app.replay !== null,
      keyForm: !$("key-form").hidden, sessions: app.sessions.map((s) => s.id),
    }),
  };
  main().catch((e) => { console.error(e); setConn("down", String(e)); });
})();
