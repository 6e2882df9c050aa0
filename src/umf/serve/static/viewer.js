// The 3-D viewer: plays a umf GLB (one skinned, coloured skeleton per person, one shared
// animation) on a floor grid with shadows, labels every person, frames everybody, and
// renders only when something changed so an idle page costs no CPU.
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";
import { CSS2DObject, CSS2DRenderer } from "three/addons/renderers/CSS2DRenderer.js";

const ELEVATION = THREE.MathUtils.degToRad(20); // front three-quarter view, as the MP4s
const AZIMUTHS = [30, -30, 60, -60, 0, 45, -45, 90, -90]; // candidate headings, degrees
const FRAMING_SAMPLES = 24; // poses sampled over the clip to find everybody's extent

export class Viewer {
  constructor(container) {
    this.container = container;
    this.fps = 30;
    this.frames = 1;
    this.time = 0;
    this.speed = 1;
    this.playing = false;
    this.dirty = true;
    this.onFrame = () => {};
    this.labels = [];
    this.people = [];

    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.renderer.shadowMap.enabled = true;
    this.renderer.shadowMap.type = THREE.PCFShadowMap;
    container.appendChild(this.renderer.domElement);

    this.labelRenderer = new CSS2DRenderer();
    Object.assign(this.labelRenderer.domElement.style, {
      position: "absolute", top: "0", left: "0", pointerEvents: "none",
    });
    container.appendChild(this.labelRenderer.domElement);

    this.scene = new THREE.Scene();
    this.scene.background = new THREE.Color(0xe9eaec);
    this.scene.fog = new THREE.Fog(0xe9eaec, 30, 80);
    this.camera = new THREE.PerspectiveCamera(40, 1, 0.05, 500);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener("change", () => { this.dirty = true; });
    this.addLights();
    this.floor = null;
    this.clock = new THREE.Clock();

    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
    this.renderer.setAnimationLoop(() => this.tick());
  }

  addLights() {
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x8d8d8d, 2.2));
    this.sun = new THREE.DirectionalLight(0xffffff, 2.0);
    this.sun.castShadow = true;
    this.sun.shadow.mapSize.set(2048, 2048);
    this.sun.shadow.bias = -0.0005;
    this.scene.add(this.sun, this.sun.target);
  }

  resize() {
    const width = Math.max(this.container.clientWidth, 1);
    const height = Math.max(this.container.clientHeight, 1);
    this.renderer.setSize(width, height);
    this.labelRenderer.setSize(width, height);
    this.camera.aspect = width / height;
    this.camera.updateProjectionMatrix();
    this.dirty = true;
  }

  // Load a GLB written by umf (Scene.save_glb) and show its first frame, paused or playing.
  async load(url, fps) {
    const gltf = await new GLTFLoader().loadAsync(url);
    this.clear();
    this.model = gltf.scene;
    this.model.traverse((node) => {
      if (node.isMesh) {
        node.castShadow = true;
        node.frustumCulled = false; // people walk away from their bind-pose bounds
      }
    });
    this.scene.add(this.model);
    this.mixer = new THREE.AnimationMixer(this.model);
    const clip = gltf.animations[0];
    if (clip) this.mixer.clipAction(clip).play();
    const extras = (gltf.asset && gltf.asset.extras) || {};
    this.fps = fps || extras.fps || 30;
    this.frames = clip ? Math.max(1, Math.round(clip.duration * this.fps) + 1) : 1;
    this.people = this.findPeople();
    this.addLabels();
    this.bounds = this.sweepBounds();
    this.fitFloor(this.bounds);
    this.frameAll();
    this.setFrame(0);
    return { frames: this.frames, fps: this.fps, text: extras.text || "", people: this.people };
  }

  clear() {
    for (const label of this.labels) label.removeFromParent();
    this.labels = [];
    if (!this.model) return;
    this.scene.remove(this.model);
    this.model.traverse((node) => {
      if (node.geometry) node.geometry.dispose();
      if (node.material) node.material.dispose();
    });
    this.model = null;
  }

  // Each person is a skinned mesh "personK_body" whose skeleton's head is "personK_head".
  findPeople() {
    const people = [];
    this.model.traverse((node) => {
      if (!node.isSkinnedMesh) return;
      const name = node.name.replace(/_body$/, "");
      const head = node.skeleton.bones.find((b) => b.name.endsWith("_head"));
      people.push({ name, head, colour: "#" + node.material.color.getHexString() });
    });
    people.sort((a, b) => a.name.localeCompare(b.name, undefined, { numeric: true }));
    return people;
  }

  addLabels() {
    this.people.forEach((person, i) => {
      if (!person.head) return;
      const div = document.createElement("div");
      div.className = "person-label";
      div.textContent = `P${i + 1}`;
      div.style.background = person.colour;
      const label = new CSS2DObject(div);
      label.position.set(0, 0.35, 0);
      person.head.add(label);
      this.labels.push(label);
    });
  }

  // Everybody's extent over the whole clip (the box of all joints at sampled times) and
  // each person's mean pelvis position, from which frameAll picks a viewing direction.
  sweepBounds() {
    const box = new THREE.Box3();
    const point = new THREE.Vector3();
    const pelvises = this.people.map((p) => p.head && p.head.parent ? this.pelvisOf(p) : null);
    this.centres = this.people.map(() => new THREE.Vector3());
    const duration = this.mixer ? (this.frames - 1) / this.fps : 0;
    for (let k = 0; k <= FRAMING_SAMPLES; k++) {
      if (this.mixer) this.mixer.setTime((duration * k) / FRAMING_SAMPLES);
      this.model.updateMatrixWorld(true);
      this.model.traverse((node) => {
        if (node.isBone) box.expandByPoint(node.getWorldPosition(point));
      });
      pelvises.forEach((bone, i) => {
        if (bone) this.centres[i].addScaledVector(bone.getWorldPosition(point), 1 / (FRAMING_SAMPLES + 1));
      });
    }
    if (box.isEmpty()) box.setFromCenterAndSize(new THREE.Vector3(0, 1, 0), new THREE.Vector3(1, 2, 1));
    box.min.y = Math.min(box.min.y, 0);
    return box;
  }

  pelvisOf(person) {
    let bone = person.head;
    while (bone.parent && bone.parent.isBone) bone = bone.parent;
    return bone;
  }

  // The front-ish heading from which the people's mean positions are furthest apart on
  // screen, so nobody hides behind somebody else (ties keep the first, the default view).
  chooseAzimuth() {
    let best = AZIMUTHS[0];
    let bestGap = -1;
    for (const degrees of AZIMUTHS) {
      const a = THREE.MathUtils.degToRad(degrees);
      const xs = this.centres.map((c) => c.x * Math.cos(a) - c.z * Math.sin(a)).sort((p, q) => p - q);
      let gap = Infinity;
      for (let i = 1; i < xs.length; i++) gap = Math.min(gap, xs[i] - xs[i - 1]);
      if (gap > bestGap + 0.05) { best = degrees; bestGap = gap; }
    }
    return THREE.MathUtils.degToRad(best);
  }

  fitFloor(box) {
    if (this.floor) {
      this.scene.remove(this.floor);
      this.floor.traverse((n) => { if (n.geometry) n.geometry.dispose(); });
    }
    const size = box.getSize(new THREE.Vector3());
    const centre = box.getCenter(new THREE.Vector3());
    const extent = Math.ceil(Math.max(size.x, size.z) + 6);
    this.floor = new THREE.Group();
    const ground = new THREE.Mesh(
      new THREE.PlaneGeometry(400, 400), // fog hides its edge
      new THREE.MeshStandardMaterial({ color: 0xe9eaec, roughness: 1 }),
    );
    ground.rotation.x = -Math.PI / 2;
    ground.receiveShadow = true;
    const grid = new THREE.GridHelper(extent, extent, 0x9a9a9a, 0xc8c8c8);
    grid.position.y = 0.002;
    this.floor.add(ground, grid);
    this.floor.position.set(Math.round(centre.x), 0, Math.round(centre.z));
    this.scene.add(this.floor);

    const radius = Math.max(size.length() / 2, 1.5) + 1;
    this.sun.position.set(centre.x + 3, centre.y + 8, centre.z + 5);
    this.sun.target.position.copy(centre);
    Object.assign(this.sun.shadow.camera, {
      left: -radius, right: radius, top: radius, bottom: -radius, near: 0.5, far: 40,
    });
    this.sun.shadow.camera.updateProjectionMatrix();
  }

  // Camera looking at the centre of everybody's whole-clip box, just far enough back that
  // all 8 corners of the box are inside the view (with a small margin).
  frameAll() {
    const box = this.bounds;
    if (!box) return;
    const azimuth = this.chooseAzimuth();
    const centre = box.getCenter(new THREE.Vector3());
    const back = new THREE.Vector3(
      Math.sin(azimuth) * Math.cos(ELEVATION), Math.sin(ELEVATION), Math.cos(azimuth) * Math.cos(ELEVATION),
    );
    const right = new THREE.Vector3(0, 1, 0).cross(back).normalize();
    const up = back.clone().cross(right);
    const tanV = Math.tan(THREE.MathUtils.degToRad(this.camera.fov) / 2);
    const tanH = tanV * this.camera.aspect;
    let distance = 1;
    for (const corner of boxCorners(box)) {
      const offset = corner.sub(centre);
      const depth = offset.dot(back);
      distance = Math.max(distance,
        depth + Math.abs(offset.dot(right)) / tanH, depth + Math.abs(offset.dot(up)) / tanV);
    }
    distance *= 1.1;
    this.camera.position.copy(centre).addScaledVector(back, distance);
    this.camera.near = Math.max(distance / 100, 0.01);
    this.camera.far = distance * 20;
    this.camera.updateProjectionMatrix();
    this.scene.fog.near = distance * 2; // the floor fades into the background far away
    this.scene.fog.far = distance * 6;
    this.controls.target.copy(centre);
    this.controls.update();
    this.dirty = true;
  }

  get frame() {
    return Math.min(Math.round(this.time * this.fps), this.frames - 1);
  }

  setFrame(k) {
    this.time = Math.max(0, Math.min(k, this.frames - 1)) / this.fps;
    this.pose();
  }

  pose() {
    if (this.mixer) this.mixer.setTime(this.time);
    this.dirty = true;
    this.onFrame(this.frame);
  }

  play() { this.playing = true; this.clock.getDelta(); }
  pause() { this.playing = false; }
  setSpeed(speed) { this.speed = speed; }

  tick() {
    const dt = this.clock.getDelta();
    if (this.playing && this.frames > 1) {
      const duration = (this.frames - 1) / this.fps;
      this.time = (this.time + dt * this.speed) % duration;
      this.pose();
    }
    if (!this.dirty) return;
    this.dirty = false;
    this.renderer.render(this.scene, this.camera);
    this.labelRenderer.render(this.scene, this.camera);
  }

  // The canvas as a PNG data URL, drawn now (what the browser test checks pixel by pixel).
  snapshot() {
    this.renderer.render(this.scene, this.camera);
    return this.renderer.domElement.toDataURL("image/png");
  }
}

function boxCorners(box) {
  const corners = [];
  for (const x of [box.min.x, box.max.x]) {
    for (const y of [box.min.y, box.max.y]) {
      for (const z of [box.min.z, box.max.z]) corners.push(new THREE.Vector3(x, y, z));
    }
  }
  return corners;
}
