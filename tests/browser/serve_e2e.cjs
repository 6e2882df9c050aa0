// Drives the `umf serve` page in headless Debian Chromium with playwright-core, as a user
// would: prompt, 3 people, person 2 told to bow, Generate, wait for the scene, scrub,
// download the GLB, re-roll person 2. Writes what it saw under OUT (PNG snapshots, the GLB, result.json); tests/test_serve_browser.py
// checks the pixels and files. Usage: node serve_e2e.cjs URL OUT
const fs = require("fs");
const os = require("os");
const path = require("path");
const { chromium } = require(process.env.PLAYWRIGHT_CORE || "playwright-core");

const [url, out] = process.argv.slice(2);
const FLAGS = [
  "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
  "--disable-background-networking", "--disable-component-update", "--disable-sync",
  "--enable-unsafe-swiftshader", // WebGL on the CPU (SwiftShader), since --disable-gpu
];

function savePng(dataUrl, name) {
  fs.writeFileSync(path.join(out, name), Buffer.from(dataUrl.split(",")[1], "base64"));
}

async function scrubTo(page, frame) {
  await page.$eval("#scrubber", (el, k) => {
    el.value = String(k);
    el.dispatchEvent(new Event("input"));
  }, frame);
  return page.evaluate(() => window.umfPage.viewer.snapshot());
}

async function main() {
  const profile = fs.mkdtempSync(path.join(os.tmpdir(), "umf-chromium-"));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: process.env.CHROMIUM || "/usr/bin/chromium",
    headless: true,
    args: FLAGS,
    viewport: { width: 1100, height: 640 },
    acceptDownloads: true,
  });
  const errors = [];
  const result = { errors };
  try {
    const page = context.pages()[0] || (await context.newPage());
    page.on("console", (msg) => { if (msg.type() === "error") errors.push(msg.text()); });
    page.on("pageerror", (err) => errors.push(String(err)));
    page.on("requestfailed", (req) => errors.push(`request failed: ${req.url()}`));
    page.setDefaultTimeout(600000); // a busy 2-core machine may be very slow; normal runs take seconds
    await page.goto(url);
    await page.waitForFunction(() => document.getElementById("status-text").textContent !== "Starting…");

    await page.fill("#prompt", "Three people walk side by side.");
    await page.fill("#people", "3");
    await page.fill("#seed", "0");
    // what each person does: one box per person, person 2 told to bow
    await page.click("#each summary");
    result.person_boxes = await page.$$eval("#person-prompts input", (els) => els.length);
    await page.fill("#person-2", "Someone bows politely.");
    const clicked = Date.now();
    await page.click("#generate");
    await page.waitForSelector("body[data-scene]", { timeout: 600000 });
    result.click_to_scene_s = (Date.now() - clicked) / 1000;
    result.person_prompts = await page.evaluate(() => window.umfPage.state.scene.person_prompts);
    result.page_click_to_scene_s = await page.evaluate(() => document.body.dataset.clickToScene);

    await page.click("#play"); // pause: the snapshots below are of chosen frames
    result.frames = await page.evaluate(() => window.umfPage.viewer.frames);
    result.people = await page.evaluate(() => window.umfPage.viewer.people.map((p) => p.colour));
    result.labels = await page.$$eval(".person-label", (els) => els.map((e) => e.textContent));
    savePng(await scrubTo(page, 0), "frame-first.png");
    savePng(await scrubTo(page, result.frames - 1), "frame-last.png");
    await scrubTo(page, Math.floor(result.frames / 2));
    await page.screenshot({ path: path.join(out, "page.png") });
    result.history = await page.$$eval("#history li", (els) => els.map((e) => e.textContent));
    result.status = await page.textContent("#status-text");

    const [download] = await Promise.all([page.waitForEvent("download"), page.click("#dl-glb")]);
    await download.saveAs(path.join(out, "download.glb"));
    result.download_name = download.suggestedFilename();

    // re-roll person 2: a new scene is shown, persons 1 and 3 as they were
    const first = await page.evaluate(() => document.body.dataset.scene);
    result.reroll_buttons = await page.$$eval("#reroll-buttons button", (els) => els.map((e) => e.textContent));
    await page.click("#reroll-p2");
    await page.waitForFunction((id) => document.body.dataset.scene !== id, first, { timeout: 600000 });
    const second = await page.evaluate(() => document.body.dataset.scene);
    result.reroll = await page.evaluate(async ([a, b]) => {
      const get = async (id) => (await (await fetch(`/api/scenes/${id}`)).json()).joints;
      const [ja, jb] = [await get(a), await get(b)];
      const same = (k) => JSON.stringify(ja[k]) === JSON.stringify(jb[k]);
      return { from: a, to: b, same: [same(0), same(1), same(2)] };
    }, [first, second]);
    result.reroll.status = await page.textContent("#status-text");
    result.reroll.history = await page.$$eval("#history li", (els) => els.map((e) => e.textContent));
  } finally {
    fs.writeFileSync(path.join(out, "result.json"), JSON.stringify(result, null, 2));
    await context.close();
    fs.rmSync(profile, { recursive: true, force: true });
  }
}

main().catch((err) => {
  console.error(err);
  process.exit(1);
});
