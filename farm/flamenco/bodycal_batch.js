// SPDX-License-Identifier: GPL-3.0-or-later
//
// BodyCal batch as a Flamenco 3 custom job type (docs/FARM.md). Install: copy this file into the
// Manager's `scripts/` folder (next to the flamenco-manager executable) and restart the Manager;
// the job type is `bodycal-batch`. Every Worker needs Blender with the BodyCal extension installed
// and enabled, and the inputs and the output folder on shared storage at the same paths.
//
// Submit with `bodycal batch JOBS.toml --export-flamenco job.json` (the jobs file checked, its
// paths made absolute) and POST job.json to the Manager's /api/v3/jobs. compileJob turns the
// recordings x avatars x methods (and animations x avatars x transfer methods) into one task per
// job, each a single `blender -b -c bodycal retarget ...` (or `transfer ...`) command: the command
// line `bodycal batch` itself runs, with the same output names (docs/FORMATS.md §4.1).

const JOB_TYPE = {
  label: "BodyCal Batch",
  description: "Retarget recordings and transfer animations onto avatars, one task per job",
  settings: [
    { key: "recordings", type: "string", required: true, default: "[]",
      description: "JSON list of {path, user}: the recordings and their user body models" },
    { key: "animations", type: "string", required: true, default: "[]",
      description: "JSON list of {path, source_armature, action}: animations to transfer" },
    { key: "avatars", type: "string", required: true,
      description: "JSON list of {file, armature, bone_map}: the avatars" },
    { key: "methods", type: "string", required: true, default: "egocentric",
      description: "comma-separated methods: egocentric, offsets, rotations" },
    { key: "output_dir", type: "string", subtype: "dir_path", required: true,
      description: "where every output goes (shared storage)" },
    { key: "export", type: "string", required: true, default: "blend",
      description: "comma-separated formats each job writes: blend, fbx, glb, gltf, bvh" },
    { key: "filter", type: "string", default: "on",
      description: "One Euro filter on the devices: on (the default parameters), off (retarget --no-filter), or parameters" },
    { key: "plant_feet", type: "bool", default: true, description: "hold the feet on the floor" },
    { key: "placement", type: "string", choices: ["object", "performer"], default: "object" },
    { key: "root_motion", type: "string", choices: ["root", "pelvis", "in-place"], default: "root" },
    { key: "rigify_target", type: "string", choices: ["fk", "def"], default: "fk" },
    { key: "tolerance", type: "string", default: "", description: "key reduction, degrees; empty: default" },
    { key: "fps", type: "string", default: "", description: "output frame rate; empty: the source's" },
    { key: "overwrite", type: "bool", default: false, description: "replace outputs that exist" },
    { key: "review", type: "bool", default: false,
      description: "every job reviews its bake; a last task writes OUTPUT_DIR/review.html" },
  ],
};

const TRANSFER_METHODS = ["egocentric", "rotations"];  // the methods `bodycal transfer` has
const PART_BYTES = 64;

function compileJob(job) {
  const s = job.settings;
  const plan = bodycalJobs(s);
  const tasks = [];
  for (const one of plan) {
    const task = author.Task(one.name, "blender");
    task.addCommand(blenderCommand(one.argv));
    job.addTask(task);
    tasks.push(task);
  }
  if (s.review === true) {  // the review page, once every job has written its review
    const page = author.Task("review-page", "blender");
    page.addCommand(blenderCommand(["review", s.output_dir]));
    for (const task of tasks) page.addDependency(task);
    job.addTask(page);
  }
}

function blenderCommand(argv) {
  return author.Command("blender-render", {
    exe: "{blender}",
    exeArgs: "-b",  // not {blenderArgs}: its usual -y would let scripts in the avatar files run
    argsBefore: ["-c", "bodycal"].concat(argv),
    args: [],
  });
}

// ---- the jobs, as app/batch.py makes them ----------------------------------------------------------

function splitList(text) {
  return String(text || "").split(",").map((x) => x.trim()).filter((x) => x.length > 0);
}

function bodycalJobs(s) {
  const recordings = JSON.parse(s.recordings || "[]");
  const animations = JSON.parse(s.animations || "[]");
  const avatars = JSON.parse(s.avatars);
  const methods = splitList(s.methods);
  const transferMethods = methods.filter((m) => TRANSFER_METHODS.indexOf(m) >= 0);
  const specs = [];
  for (const r of recordings) {
    for (const a of avatars) {
      for (const m of methods) specs.push({ rec: r.path, user: r.user, avatar: a, method: m, anim: null });
    }
  }
  for (const an of animations) {
    for (const a of avatars) {
      for (const m of transferMethods) specs.push({ rec: an.path, user: null, avatar: a, method: m, anim: an });
    }
  }
  const names = outputNames(specs);
  return specs.map((spec, k) => ({ name: names[k], argv: jobArgv(spec, names[k], s) }));
}

function jobArgv(spec, name, s) {
  const a = spec.avatar;
  let argv;
  if (spec.user === null) {
    argv = ["transfer", spec.rec, "--avatar", a.file, "--method", spec.method];
    if (spec.anim.source_armature) argv.push("--source-armature", spec.anim.source_armature);
    if (spec.anim.action) argv.push("--action", spec.anim.action);
  } else {
    argv = ["retarget", spec.rec, "--user", spec.user, "--avatar", a.file, "--method", spec.method];
  }
  for (const format of splitList(s.export || "blend")) argv.push("-o", joinPath(s.output_dir, `${name}.${format}`));
  if (s.tolerance !== undefined && s.tolerance !== "") argv.push("--tolerance", pyFloat(s.tolerance));
  if (s.fps !== undefined && s.fps !== "") argv.push("--fps", pyFloat(s.fps));
  if (a.armature) argv.push("--armature", a.armature);
  if (a.bone_map) argv.push("--bone-map", a.bone_map);
  if (spec.user !== null && s.filter === "off") argv.push("--no-filter");  // tracker smoothing: recordings only
  else if (spec.user !== null && s.filter && s.filter !== "on") argv.push("--filter", s.filter);
  if (s.plant_feet === false) argv.push("--no-plant-feet");
  if (s.placement && s.placement !== "object") argv.push("--placement", s.placement);
  if (s.root_motion && s.root_motion !== "root") argv.push("--root-motion", s.root_motion);
  if (s.rigify_target && s.rigify_target !== "fk") argv.push("--rigify-target", s.rigify_target);
  if (s.overwrite === true) argv.push("--overwrite");
  if (s.review === true) argv.push("--review");
  return argv;
}

// Python's repr(float(x)): "30.0", "0.25".
function pyFloat(text) {
  const x = Number(text);
  return Number.isInteger(x) ? `${x}.0` : String(x);
}

// ---- output names: docs/FORMATS.md §4.1 ------------------------------------------------------------

function baseName(path) {
  const parts = path.split("/");
  return parts[parts.length - 1];
}

function parentName(path) {
  const parts = path.split("/");
  return parts.length > 1 ? parts[parts.length - 2] : "";
}

function joinPath(folder, name) {
  return folder.endsWith("/") ? folder + name : `${folder}/${name}`;
}

function stem(path) {
  return baseName(path).split(".")[0];
}

function normPath(path) {
  const out = [];
  for (const part of path.split("/")) {
    if (part === "" || part === ".") continue;
    if (part === "..") out.pop();
    else out.push(part);
  }
  return "/" + out.join("/");
}

function utf8Length(codePoint) {
  return codePoint < 0x80 ? 1 : codePoint < 0x800 ? 2 : codePoint < 0x10000 ? 3 : 4;
}

function safePart(text) {
  let s = text.normalize("NFC").replace(/[^\p{L}\p{N}_.+-]/gu, "_");
  s = s.replace(/\.{2,}/g, "_").replace(/_{2,}/g, "_").replace(/^[.-]+/, "");
  let cut = "";
  let bytes = 0;
  for (const ch of s) {
    bytes += utf8Length(ch.codePointAt(0));
    if (bytes > PART_BYTES) break;
    cut += ch;
  }
  cut = cut.replace(/\.+$/, "");
  return cut || "unnamed";
}

// Python's json.dumps of a list of strings and nulls (ensure_ascii, ", " between items).
function pyJson(items) {
  const escapes = { '"': '\\"', "\\": "\\\\", "\n": "\\n", "\r": "\\r", "\t": "\\t", "\b": "\\b", "\f": "\\f" };
  const one = (v) => {
    if (v === null || v === undefined) return "null";
    let out = '"';
    for (let i = 0; i < v.length; i++) {
      const c = v[i];
      const code = v.charCodeAt(i);
      if (escapes[c]) out += escapes[c];
      else if (code < 0x20 || code > 0x7e) out += "\\u" + code.toString(16).padStart(4, "0");
      else out += c;
    }
    return out + '"';
  };
  return "[" + items.map(one).join(", ") + "]";
}

function jobHash(spec) {
  const a = spec.avatar;
  const items = [normPath(spec.rec), spec.user === null ? null : normPath(spec.user), normPath(a.file),
    a.armature || null, spec.method];
  if (spec.user === null) items.push(spec.anim.action || null);
  return sha256Hex(pyJson(items)).slice(0, 8);
}

function outputNames(specs) {
  const parts = specs.map((spec) => {
    const act = spec.anim ? spec.anim.action : null;
    const rec = safePart(act ? `${stem(spec.rec)}-${act}` : stem(spec.rec));
    return { rec, recInFolder: `${safePart(parentName(spec.rec))}-${rec}`,
      avatar: safePart(spec.avatar.armature || stem(spec.avatar.file)), method: spec.method, digest: jobHash(spec) };
  });
  const level = specs.map(() => 0);
  const name = (k) => {
    const p = parts[k];
    const text = `${level[k] === 0 ? p.rec : p.recInFolder}__${p.avatar}__${p.method}`;
    return level[k] === 2 ? `${text}__${p.digest}` : text;
  };
  for (;;) {
    const groups = {};
    specs.forEach((_, k) => {
      const key = name(k).toLowerCase();
      (groups[key] = groups[key] || []).push(k);
    });
    const clashes = Object.keys(groups).map((key) => groups[key]).filter((ks) => ks.length > 1);
    if (clashes.length === 0) return specs.map((_, k) => name(k));
    for (const ks of clashes) {
      if (ks.every((k) => level[k] === 2)) throw new Error(`two jobs get the same output name ${name(ks[0])}`);
      for (const k of ks) level[k] = Math.min(level[k] + 1, 2);
    }
  }
}

// SHA-256 of an ASCII string (the hashed text is ASCII: pyJson escapes the rest). Flamenco's
// JavaScript has no crypto module.
function sha256Hex(ascii) {
  const K = [];
  const H = [];
  let n = 2;
  for (let found = 0; found < 64; n++) {
    let prime = true;
    for (let d = 2; d * d <= n; d++) if (n % d === 0) { prime = false; break; }
    if (!prime) continue;
    if (found < 8) H.push((Math.pow(n, 1 / 2) * 0x100000000) | 0);
    K.push((Math.pow(n, 1 / 3) * 0x100000000) | 0);
    found++;
  }
  const bytes = [];
  for (let i = 0; i < ascii.length; i++) bytes.push(ascii.charCodeAt(i) & 0xff);
  const bitLength = bytes.length * 8;
  bytes.push(0x80);
  while (bytes.length % 64 !== 56) bytes.push(0);
  for (let shift = 56; shift >= 0; shift -= 8) bytes.push(shift >= 32 ? 0 : (bitLength >>> shift) & 0xff);
  const rotr = (x, r) => (x >>> r) | (x << (32 - r));
  const w = new Array(64);
  for (let off = 0; off < bytes.length; off += 64) {
    for (let i = 0; i < 16; i++) {
      w[i] = (bytes[off + 4 * i] << 24) | (bytes[off + 4 * i + 1] << 16) | (bytes[off + 4 * i + 2] << 8) | bytes[off + 4 * i + 3];
    }
    for (let i = 16; i < 64; i++) {
      const s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >>> 3);
      const s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >>> 10);
      w[i] = (w[i - 16] + s0 + w[i - 7] + s1) | 0;
    }
    let [a, b, c, d, e, f, g, h] = H;
    for (let i = 0; i < 64; i++) {
      const t1 = (h + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + K[i] + w[i]) | 0;
      const t2 = ((rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c))) | 0;
      h = g; g = f; f = e; e = (d + t1) | 0; d = c; c = b; b = a; a = (t1 + t2) | 0;
    }
    [a, b, c, d, e, f, g, h].forEach((v, i) => { H[i] = (H[i] + v) | 0; });
  }
  return H.map((v) => (v >>> 0).toString(16).padStart(8, "0")).join("");
}
