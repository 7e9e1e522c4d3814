"""Check that every relative link in README.md and docs/*.md resolves inside the repository:
files, folders and #anchors of Markdown files (slugged as GitHub does). Also prints the README's
line count. Usage: python docs/check_links.py [REPO_ROOT]; exit code 1 when a link is broken."""
import re
import sys
import unicodedata
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).parent.parent).resolve()
files = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
link = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")

def slug(h):
    h = re.sub(r"`", "", h.strip().lower())
    out = []
    for ch in h:
        cat = unicodedata.category(ch)
        if ch in " -_" or cat[0] in "LN":
            out.append("-" if ch == " " else ch)
    return "".join(out)

def anchors(md):
    seen, out = {}, set()
    in_code = False
    for line in md.read_text().splitlines():
        if line.startswith("```"):
            in_code = not in_code
        if in_code:
            continue
        m = re.match(r"#{1,6}\s+(.*)", line)
        if m:
            s = slug(m.group(1))
            n = seen.get(s, 0)
            out.add(s if n == 0 else f"{s}-{n}")
            seen[s] = n + 1
    return out

bad = 0
for f in files:
    text = re.sub(r"```.*?```", "", f.read_text(), flags=re.S)
    for target in link.findall(text):
        if re.match(r"[a-z]+:", target):
            continue
        path, _, frag = target.partition("#")
        dest = (f.parent / path).resolve() if path else f
        ok = dest.exists() and (root in dest.parents or dest == root)
        if ok and frag:
            ok = dest.suffix == ".md" and frag in anchors(dest)
        if not ok:
            bad += 1
            print(f"{f.relative_to(root)}: {target}")
n = sum(1 for l in (root / "README.md").read_text().splitlines())
print(f"{bad} broken link(s); README.md {n} lines")
sys.exit(1 if bad else 0)
