"""MkDocs hook: links from a page to files of the repository outside docs/ (a benchmark script, a
result file, a chart, a bundled scene) are kept as they are written, relative to the page, so that
they work on a checkout and on a code host, and the files they name are copied into the site under
``repo/`` so that they work there too.

A link whose target does not exist is left alone, and MkDocs reports it as not found (a failure
under ``--strict``). Markdown files outside docs/ cannot be linked this way (MkDocs would take them
for pages); name them as code instead.
"""

from __future__ import annotations

import logging
import posixpath
import re
from pathlib import Path

from mkdocs.structure.files import File

log = logging.getLogger("mkdocs.hooks.repo_files")

# [text](target) and ![alt](target), with an optional "title"
LINK = re.compile(r"\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")


def on_page_markdown(markdown, page, config, files):
    docs_dir = Path(config["docs_dir"]).resolve()
    root = Path(config["config_file_path"]).resolve().parent
    for target in LINK.findall(markdown):
        if "://" in target or target.startswith(("#", "/", "mailto:")):
            continue
        path = target.split("#", 1)[0].split("?", 1)[0]
        uri = posixpath.normpath(posixpath.join(posixpath.dirname(page.file.src_uri), path))
        if not uri.startswith("../") or files.get_file_from_path(uri) is not None:
            continue
        source = (docs_dir / uri).resolve()
        if root not in source.parents or not source.is_file():
            continue  # MkDocs reports it as not found
        if source.suffix == ".md":
            log.warning(f"{page.file.src_uri}: links to {uri}, a Markdown file outside docs/; name it as code")
            continue
        inside = source.relative_to(root).as_posix()
        files.append(
            File(
                uri,
                src_dir=str(docs_dir),
                dest_dir=config["site_dir"],
                use_directory_urls=config["use_directory_urls"],
                dest_uri=f"repo/{inside}",
            )
        )
    return markdown
