// Vendors the pinned three.js build (module + OrbitControls + its license) into the Python
// package, service/static/vendor/. The viewer itself is written directly as ES modules in
// service/static/ (no bundler: the page loads them through an import map), so there is one
// copy of its code. Run `npm ci && npm run build` here after changing the three.js pin.
import { copyFileSync, mkdirSync, rmSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const vendor = join(here, "..", "service", "static", "vendor");
const three = join(here, "node_modules", "three");

rmSync(vendor, { recursive: true, force: true });
mkdirSync(join(vendor, "addons", "controls"), { recursive: true });
copyFileSync(join(three, "build", "three.module.min.js"), join(vendor, "three.module.min.js"));
copyFileSync(join(three, "examples", "jsm", "controls", "OrbitControls.js"),
             join(vendor, "addons", "controls", "OrbitControls.js"));
copyFileSync(join(three, "LICENSE"), join(vendor, "LICENSE.three.txt"));
console.log(`three.js vendored into ${vendor}`);
