// Copies the viewer into the Python package: src/* -> service/static/, and the pinned three.js
// build (module + OrbitControls + its license) -> service/static/vendor/. No bundler: the page
// loads ES modules through an import map. Run `npm ci && npm run build` after editing src/.
import { copyFileSync, mkdirSync, readdirSync, rmSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const out = join(here, "..", "service", "static");
const three = join(here, "node_modules", "three");

rmSync(out, { recursive: true, force: true });
mkdirSync(join(out, "vendor", "addons", "controls"), { recursive: true });
for (const name of readdirSync(join(here, "src"))) copyFileSync(join(here, "src", name), join(out, name));
copyFileSync(join(three, "build", "three.module.min.js"), join(out, "vendor", "three.module.min.js"));
copyFileSync(join(three, "examples", "jsm", "controls", "OrbitControls.js"),
             join(out, "vendor", "addons", "controls", "OrbitControls.js"));
copyFileSync(join(three, "LICENSE"), join(out, "vendor", "LICENSE.three.txt"));
console.log(`viewer built into ${out}`);
