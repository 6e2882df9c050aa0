// The page: the form, the JSON API calls, progress, downloads, the history and the player
// controls around the 3-D viewer (viewer.js).
import { Viewer } from "/static/viewer.js";

const $ = (id) => document.getElementById(id);
const viewer = new Viewer($("viewer"));
const state = { scene: null, actor: null, history: [] };
window.umfPage = { viewer, state }; // for the browser test and for curious users

// ---------------------------------------------------------------- status and progress
function setStatus(text, { busy = false, error = false, value = null, max = null } = {}) {
  $("status-text").textContent = text;
  $("status").classList.toggle("error", error);
  const bar = $("progress");
  bar.hidden = !busy;
  if (value === null) bar.removeAttribute("value");
  else { bar.max = max; bar.value = value; }
}

async function api(path, options = {}) {
  const response = await fetch(path, options);
  const body = await response.json().catch(() => ({ error: `HTTP ${response.status}` }));
  if (!response.ok) throw new Error(body.error || `HTTP ${response.status}`);
  return body;
}

const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));

// While a generation request is pending, say whether the model is still loading.
async function watchGeneration(pending) {
  const begin = performance.now();
  let done = false;
  pending.then(() => { done = true; }, () => { done = true; }); // generate() reports errors
  while (!done) {
    const seconds = ((performance.now() - begin) / 1000).toFixed(1);
    try {
      const health = await api("/api/health");
      const loading = health.model.state === "loading" || health.model.state === "idle";
      if (!done) setStatus(loading ? `Loading the model… ${seconds} s` : `Generating… ${seconds} s`, { busy: true });
    } catch { /* the answer to the request itself reports failures */ }
    await sleep(250);
  }
}

// ---------------------------------------------------------------- the form
function numberOrNull(id) {
  const value = $(id).value.trim();
  return value === "" ? null : Number(value);
}

function request() {
  const body = {
    prompt: $("prompt").value,
    people: Number($("people").value),
    seconds: Number($("seconds").value),
    seed: Number($("seed").value),
    guidance: numberOrNull("guidance"),
    steps: $("steps").value.trim() || null,
    sflow_steps: numberOrNull("sflow-steps"),
    joints: false,
  };
  if ($("use-actor").checked && state.actor) {
    body.actor = state.actor.actor;
    body.actor_person = Number($("actor-person").value);
    body.start = Number($("actor-start").value);
  }
  const own = personPrompts();
  if (own.some((p) => p !== null)) body.person_prompts = own;
  return body;
}

// One optional text box per person: the K-th box is person K's own prompt.
function setPersonBoxes() {
  const box = $("person-prompts");
  const people = Math.max(1, Math.min(16, Number($("people").value) || 1));
  while (box.children.length < people) {
    const k = box.children.length + 1;
    const label = document.createElement("label");
    label.textContent = `Person ${k} `;
    const input = document.createElement("input");
    input.type = "text";
    input.id = `person-${k}`;
    input.maxLength = 500;
    input.placeholder = k === 1 ? "e.g. raises both hands" : "e.g. bows";
    label.appendChild(input);
    box.appendChild(label);
  }
  while (box.children.length > people) box.lastChild.remove();
}

function personPrompts() {
  const inputs = [...$("person-prompts").querySelectorAll("input")];
  const own = inputs.map((input) => input.value.trim() || null);
  while (own.length && own[own.length - 1] === null) own.pop();
  return own;
}

async function generate(event) {
  event.preventDefault();
  $("generate").disabled = true;
  const clicked = performance.now();
  const pending = api("/api/generate", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(request()),
  });
  watchGeneration(pending);
  try {
    const scene = await pending;
    addHistory(scene);
    await show(scene);
    const seconds = ((performance.now() - clicked) / 1000).toFixed(1);
    setStatus(`${scene.people} people, ${scene.seconds} s, seed ${scene.seed}: shown ${seconds} s after the click`);
    document.body.dataset.clickToScene = seconds;
  } catch (error) {
    setStatus(error.message, { error: true });
  } finally {
    $("generate").disabled = false;
  }
}

async function upload() {
  const file = $("actor-file").files[0];
  state.actor = null;
  $("use-actor").checked = false;
  $("use-actor").disabled = true;
  if (!file) return;
  setStatus(`Reading ${file.name}…`, { busy: true });
  try {
    state.actor = await api(`/api/upload?name=${encodeURIComponent(file.name)}`, {
      method: "POST",
      headers: { "Content-Type": "application/octet-stream" },
      body: file,
    });
    $("use-actor").disabled = false;
    $("use-actor").checked = true;
    $("actor-person").max = state.actor.people;
    const people = state.actor.people === 1 ? "1 person" : `${state.actor.people} people`;
    $("actor-info").textContent = `${state.actor.name}: ${state.actor.seconds} s, ${people}`;
    if (Number($("people").value) < 2) $("people").value = 2;
    setStatus(`${file.name} is person 1 of the next scene`);
  } catch (error) {
    $("actor-info").textContent = "";
    setStatus(error.message, { error: true });
  }
}

// ---------------------------------------------------------------- showing a scene
async function show(scene) {
  state.scene = scene;
  setStatus("Loading the scene into the viewer…", { busy: true });
  await viewer.load(scene.files.glb, scene.fps);
  $("caption").textContent = scene.text;
  const warnings = [];
  const cov = scene.coverage;
  if (cov && cov.known === false) {
    warnings.push(`Outside what this model was trained on (coverage ${cov.score.toFixed(2)}); nearest known: ${cov.nearest.join("; ")}`);
  }
  (scene.person_coverage || []).forEach((c, i) => {
    if (c && c.known === false) {
      warnings.push(`Person ${i + 1}'s prompt is outside what this model was trained on (coverage ${c.score.toFixed(2)}); nearest known: ${c.nearest.join("; ")}`);
    }
  });
  $("coverage").hidden = warnings.length === 0;
  $("coverage").textContent = warnings.join(" ");
  $("scrubber").max = viewer.frames - 1;
  setDownloads(scene);
  setReroll(scene);
  markCurrent(scene.id);
  viewer.play();
  $("play").textContent = "Pause";
  document.body.dataset.scene = scene.id; // the browser test waits for this
}

// One button per person: that person generated again as a reaction to all the others.
function setReroll(scene) {
  const box = $("reroll-buttons");
  box.replaceChildren();
  $("reroll").hidden = !(scene.files.npz && scene.people > 1);
  for (let person = 1; person <= scene.people; person++) {
    const button = document.createElement("button");
    button.type = "button";
    button.id = `reroll-p${person}`;
    button.textContent = `P${person}`;
    button.title = `Generate person ${person} again with a new seed`;
    button.addEventListener("click", () => reroll(scene, person));
    box.append(button);
  }
}

async function reroll(scene, person) {
  const buttons = $("reroll-buttons").querySelectorAll("button");
  buttons.forEach((b) => { b.disabled = true; });
  const seed = Math.floor(Math.random() * 2 ** 31);
  const body = { scene: scene.id, person, seed, joints: false };
  // a filled box "Person K" tells the re-rolled person what to do; empty: as recorded
  const own = personPrompts()[person - 1];
  if (own) body.person_prompt = own;
  const pending = api("/api/reroll", {
    method: "POST",
    headers: { "Content-Type": "application/json" },
    body: JSON.stringify(body),
  });
  watchGeneration(pending);
  try {
    const again = await pending;
    addHistory(again);
    await show(again);
    setStatus(`Person ${person} re-rolled (seed ${seed}); everyone else as before`);
  } catch (error) {
    setStatus(error.message, { error: true });
  } finally {
    buttons.forEach((b) => { b.disabled = false; });
  }
}

function setDownloads(scene) {
  $("downloads").hidden = false;
  for (const kind of ["glb", "bvh", "npz"]) {
    const link = $(`dl-${kind}`);
    link.hidden = !scene.files[kind];
    if (scene.files[kind]) link.href = scene.files[kind];
  }
  $("dl-mp4").hidden = !scene.files.mp4;
  $("dl-mp4").disabled = false;
}

// The MP4 is encoded on demand in the server; poll its progress, then download it.
async function downloadVideo() {
  const scene = state.scene;
  $("dl-mp4").disabled = true;
  try {
    let video = await api(scene.files.mp4, { method: "POST" });
    while (video.state === "running") {
      setStatus(`Encoding the video… frame ${video.done} of ${video.total}`,
        { busy: true, value: video.done, max: video.total || 1 });
      await sleep(300);
      video = await api(scene.files.mp4);
    }
    if (video.state !== "done") throw new Error(`video encoding failed: ${video.error}`);
    setStatus("Video ready");
    const link = document.createElement("a");
    link.href = video.url;
    link.download = "";
    link.click();
  } catch (error) {
    setStatus(error.message, { error: true });
  } finally {
    $("dl-mp4").disabled = false;
  }
}

// ---------------------------------------------------------------- history
function addHistory(scene) {
  state.history.push(scene);
  const item = document.createElement("li");
  item.dataset.id = scene.id;
  const seed = scene.seed === null || scene.seed === undefined ? "" : ` (seed ${scene.seed})`;
  const again = scene.reroll ? `, P${scene.reroll.person} re-rolled (seed ${scene.reroll.seed})` : "";
  item.textContent = `${scene.text}${seed}${again}, ${scene.people} p.`;
  item.title = "Show this scene again";
  item.addEventListener("click", () => show(scene).then(() => setStatus(`Showing: ${scene.text}`)));
  $("history").prepend(item);
}

function markCurrent(id) {
  for (const item of $("history").children) item.classList.toggle("current", item.dataset.id === id);
}

// ---------------------------------------------------------------- player controls
function bindPlayer() {
  viewer.onFrame = (frame) => {
    $("scrubber").value = frame;
    $("frame-label").textContent = `${frame + 1} / ${viewer.frames}`;
  };
  $("play").addEventListener("click", togglePlay);
  $("scrubber").addEventListener("input", () => {
    viewer.pause();
    $("play").textContent = "Play";
    viewer.setFrame(Number($("scrubber").value));
  });
  $("speed").addEventListener("change", () => viewer.setSpeed(Number($("speed").value)));
  $("frame-all").addEventListener("click", () => viewer.frameAll());
  document.addEventListener("keydown", (event) => {
    if (event.code === "Space" && event.target === document.body) {
      event.preventDefault();
      togglePlay();
    }
  });
}

function togglePlay() {
  if (viewer.playing) viewer.pause(); else viewer.play();
  $("play").textContent = viewer.playing ? "Pause" : "Play";
}

// ---------------------------------------------------------------- start
async function start() {
  bindPlayer();
  $("form").addEventListener("submit", generate);
  $("new-seed").addEventListener("click", () => {
    $("seed").value = Math.floor(Math.random() * 2 ** 31);
  });
  $("actor-file").addEventListener("change", upload);
  $("people").addEventListener("input", setPersonBoxes);
  setPersonBoxes();
  $("dl-mp4").addEventListener("click", downloadVideo);
  try {
    const health = await api("/api/health");
    const { scenes } = await api("/api/scenes");
    scenes.forEach(addHistory);
    if (scenes.length) await show(scenes[scenes.length - 1]);
    const model = health.model.state === "ready" ? `model ${health.model.name} ready`
      : health.model.state === "error" ? `model error: ${health.model.error}`
      : health.model.state === "idle" ? "the model loads when you first generate"
      : "the model loads in the background";
    setStatus(`Type a prompt and press Generate (${model}).`, { error: health.model.state === "error" });
  } catch (error) {
    setStatus(`The server does not answer: ${error.message}`, { error: true });
  }
}

start();
