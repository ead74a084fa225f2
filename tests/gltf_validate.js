// The Khronos glTF validator's report of one file (its "issues": numErrors, numWarnings,
// messages) as JSON on stdout: node tests/gltf_validate.js FILE, with NODE_PATH naming the
// node_modules folder that holds gltf-validator.
const fs = require("fs");
const validator = require("gltf-validator");

validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])))
  .then((report) => console.log(JSON.stringify(report.issues)))
  .catch((error) => { console.error(String(error)); process.exit(1); });
