// Validates glTF/GLB files with the Khronos glTF-Validator and prints one JSON line per file:
// {"file": ..., "errors": N, "warnings": N, "messages": [first error messages]}.
// Exit code 0 even when files have errors: the Rust test decides.
import { readFile } from 'node:fs/promises';
import validator from 'gltf-validator';

for (const file of process.argv.slice(2)) {
  const bytes = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(bytes, {
    maxIssues: 200,
    externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} not allowed`)),
  });
  const issues = report.issues;
  const messages = issues.messages
    .filter((m) => m.severity === 0)
    .slice(0, 10)
    .map((m) => `${m.code} ${m.pointer ?? ''}: ${m.message}`);
  console.log(JSON.stringify({ file, errors: issues.numErrors, warnings: issues.numWarnings, messages }));
}
